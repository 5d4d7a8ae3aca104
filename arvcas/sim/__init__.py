"""The closed-loop experiment: the scenario (:mod:`.scenario`), the run's time table
(:mod:`.schedule`), the closed loop as one CasADi function (:mod:`.closedloop`) and the Python API
(:mod:`.simulation`)."""
