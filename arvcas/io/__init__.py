"""Files and figures: HDF5 results (:mod:`.results`) and plots (:mod:`.plots`)."""
