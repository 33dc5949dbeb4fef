"""rovlab: model, identify, estimate, control and simulate small underwater vehicles.

Units are SI and radians inside; NED world frame, FRD body frame; SNAME names and signs.
See docs/conventions.md.

Importing rovlab changes nothing outside it: no environment variable, no setting of numba or of
any other library (the compiled kernels go through numba's own cache, rovlab._jit).
"""

from __future__ import annotations

__version__ = "0.1.0"
