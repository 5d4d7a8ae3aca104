"""Beyond the paper: implicit GSTA closed loop, sampling-period sweep, Monte Carlo robustness, robust fronts."""
