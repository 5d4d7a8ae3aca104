"""From graphs to machine code: code generation and the compile cache (:mod:`.codegen`), calling
compiled functions on NumPy arrays (:mod:`.calls`), and exporting C for other programs (:mod:`.export`)."""
