"""The closed-loop experiment: the scenario (:mod:`.scenario`) and the signals it prescribes
(:mod:`.profiles`), the run's time table (:mod:`.schedule`), the estimator (:mod:`.ekf`) and the thrusters'
forcing (:mod:`.thrust_forcing`) of one sample, the closed loop as one CasADi function (:mod:`.closedloop`)
and the Python API (:mod:`.simulation`)."""
