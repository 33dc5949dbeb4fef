"""Identification from lab experiments (Sandøy 2016, sec. 2.3 and ch. 4) and the virtual lab that rehearses them.

One module per experiment, each a pure function from arrays (or a loaded data table) to a
frozen result holding the estimates, their standard errors, the residuals and a quality measure:

* :mod:`rovlab.ident.thrust`     thrust curves from a load-cell staircase or a static table (9.1)
* :mod:`rovlab.ident.towing`     surge/sway/heave damping from towing-carriage runs (9.2)
* :mod:`rovlab.ident.yaw`        yaw damping from constant-moment runs (9.3)
* :mod:`rovlab.ident.added_mass` added mass from geometry, DNV-RP-H103 / Eidsvik (9.4)
* :mod:`rovlab.ident.step`       first-order model from a step/relay response (9.5)
* :mod:`rovlab.ident.noise`      sensor variances from resting logs (9.6)
* :mod:`rovlab.ident.lab`        the virtual lab: realistic data for each of them, seeded
* :mod:`rovlab.ident.plots`      PNG figures of each fit (needs the ``plot`` extra)

Signs follow SNAME (Fossen 2011; Sandøy 2016, sec. 3.1): identified added-mass and damping derivatives are negative.
"""

from rovlab.ident.added_mass import AddedMassEstimate, added_mass_dnv, added_mass_from_vehicle
from rovlab.ident.fitting import IdentificationError
from rovlab.ident.noise import NoiseEstimate, noise_variances
from rovlab.ident.step import StepFit, fit_step_response
from rovlab.ident.thrust import ThrustFit, fit_thrust_curve, fit_thrust_log
from rovlab.ident.towing import DampingFit, identify_towing
from rovlab.ident.yaw import identify_yaw

__all__ = [
    "AddedMassEstimate", "DampingFit", "IdentificationError", "NoiseEstimate", "StepFit", "ThrustFit",
    "added_mass_dnv", "added_mass_from_vehicle", "fit_step_response", "fit_thrust_curve", "fit_thrust_log",
    "identify_towing", "identify_yaw", "noise_variances",
]
