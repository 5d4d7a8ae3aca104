"""Files and figures: reading and writing any file (:mod:`.files`: input and output policies, the atomic
writer), HDF5 results (:mod:`.results`) and plots (:mod:`.plots`)."""
