"""Results and figures: HDF5 results (:mod:`.results`), MATLAB files (:mod:`.matfile`), plots (:mod:`.plots`)
in the house style (:mod:`.style`), the command line's shared argument checks (:mod:`.cliargs`) and ArduSub
parameter files (:mod:`.ardusub_params`). Reading and writing any file goes through :mod:`arvcas.util.files`."""
