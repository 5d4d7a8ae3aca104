"""A real vehicle's logs in arvcas: read and align them, validate a system on them, identify its parameters.

* :mod:`arvcas.ident.logs`: a log mapping file (``*.log.toml``, docs/logs.md) -> a :class:`Log`: CSV files or
  a ROS 2 bag (MCAP or sqlite3, through the ``rosbags`` package), streams resampled on one time base, in
  the model's frames (NED world, FRD body, ZYX Euler angles without jumps), the joints as smoothing
  splines (positions, rates and accelerations);
* :mod:`arvcas.ident.plant`: the open-loop plant driven by a log (thrust or zero thrust, the joints
  prescribed), as one compiled RK4 step over a block of samples;
* :mod:`arvcas.ident.validate`: simulation error per trial and signal (RMSE, NRMSE, R^2, largest error);
* :mod:`arvcas.ident.identify`: grey-box estimation of named system parameters by multiple shooting with
  IPOPT, 95 % intervals from the Gauss-Newton information, unidentifiable directions named.

This layer sits above the simulation and tuning layers (it uses the model, the build cache and the
file policies of :mod:`arvcas.util.files`) and below the experiments and the command line, which write
its reports.
"""
