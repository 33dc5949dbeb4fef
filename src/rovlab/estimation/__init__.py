"""State estimation, one module per role (Sandøy 2016, sec. 5.1):

* ``model``       -- the depth-and-heading observer model from a vehicle and a configuration,
                     measurement channels, observability check
* ``layout``      -- the columns and codes of sensor management's arrays (no numba)
* ``fusion``      -- per-channel sensor management: timeouts, non-finite samples, chi-square gate,
                     transitional variance, manual override (compiled)
* ``kalman``      -- the discrete Kalman filter's compiled kernels
* ``filtering``   -- the filter from Python: Belief, Report, FilterRun, DepthHeadingFilter
* ``streaming``   -- a long log through an offline filter in chunks (StreamingFilter)
* ``kf``, ``ekf`` -- the estimator components of the loop: the depth-and-heading filter, the 4-DOF EKF
* ``offline``     -- any estimator component over a log (``rovlab filter --estimator``)
* ``consistency`` -- NEES / NIS with chi-square bounds for Monte Carlo checks

Submodules are imported explicitly (``from rovlab.estimation.filtering import DepthHeadingFilter``),
so importing one does not pull in the others.
"""
