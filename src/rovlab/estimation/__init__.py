"""State estimation, one module per role (Sandøy 2016, sec. 5.1):

* ``discretise``  -- zero-order-hold discretisation and Van Loan's process-noise covariance
* ``model``       -- the depth-and-heading observer model from a vehicle and a configuration,
                     measurement channels, observability check
* ``fusion``      -- per-channel sensor management: timeouts, non-finite samples, chi-square gate,
                     transitional variance, manual override (compiled)
* ``kalman``      -- the discrete Kalman filter: compiled kernels, Belief, DepthHeadingFilter
* ``consistency`` -- NEES / NIS with chi-square bounds for Monte Carlo checks

Submodules are imported explicitly (``from rovlab.estimation.filtering import DepthHeadingFilter``),
so importing one does not pull in the others.
"""
