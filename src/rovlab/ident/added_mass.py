"""Added mass from the box geometry: Eidsvik's empirical method on DNV-RP-H103 tables (Sandøy 2016, sec. 4.2.1).

The vehicle is treated as a box L x W x H whose projected areas scale the result:

    c_xy = A_top / (L W),  c_yz = A_front / (H W),  c_xz = A_side / (L H)

    surge, 3-D:     a = (H + W)/2, C_3 = prism(L/a), V_R = a^2 L,  X_3 = rho C_3 V_R c_yz^2 c_xz c_xy
    surge, strip:   X_s = rho rect_CA(W/L) pi (W/2)^2 c_yz^2 c_xz c_xy H
    scale:          lambda = sqrt(X_3 / X_s),  X_udot = -lambda X_s
    sway:           Y_vdot = -lambda rho rect_CA(L/W) pi (L/2)^2 c_xz^2 c_xy c_yz H
    heave:          Z_wdot = -lambda rho rect_CA(L/W) pi (L/2)^2 c_xy^2 c_xz c_yz W
    yaw:            N_rdot = -lambda rho rect_beta(W/L) pi (L/2)^4 c_yz c_xy c_xz H

(with the plane labels of the thesis's table 4.2 corrected; Eidsvik 2015; Sandøy 2016
sec. 4.2.1.) The DNV tables (``dnv_rp_h103.toml`` next to this file, DNV-RP-H103 appendix A,
tables A-1 and A-2) are interpolated with not-a-knot cubic splines that extrapolate; a ratio
outside a table's range is reported in ``extrapolated``.

The method has no standard errors; its quality measures are how far the box is from the square
cross-section the 3-D data assume (Eidsvik's rule of thumb: the two cross-section sides within
+-10 %) and whether any table was extrapolated.
"""

from __future__ import annotations

import functools
import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np

from rovlab.ident.fitting import IdentificationError

ADDED_MASS_KEYS = ("X_udot", "Y_vdot", "Z_wdot", "N_rdot")


@dataclass(frozen=True)
class DnvTables:
    rect_a_over_b: np.ndarray  # table A-1: 2-D rectangle, a/b
    rect_CA: np.ndarray
    rect_beta: np.ndarray
    prism_b_over_a: np.ndarray  # table A-2: square prism, b/a
    prism_CA: np.ndarray


@functools.lru_cache(maxsize=1)
def dnv_tables() -> DnvTables:
    """The packaged DNV-RP-H103 tables (see the source comments in dnv_rp_h103.toml)."""
    text = (resources.files("rovlab.ident") / "dnv_rp_h103.toml").read_text(encoding="utf-8")
    data = tomllib.loads(text)
    r, p = data["table_a1_rectangle"], data["table_a2_square_prism"]
    return DnvTables(np.array(r["a_over_b"], float), np.array(r["C_A"], float), np.array(r["beta"], float),
                     np.array(p["b_over_a"], float), np.array(p["C_A"], float))


def _spline(x: np.ndarray, y: np.ndarray):
    """The not-a-knot cubic spline through (x, y) as a function of x (numbers or arrays),
    extrapolated with its end pieces (what
    scipy.interpolate.CubicSpline(..., bc_type="not-a-knot", extrapolate=True) gives, without
    scipy.interpolate's 0.5 s import in a one-shot command; tests compare the two).

    The knot slopes s solve the C2 conditions at the interior knots,
    dx_i s_{i-1} + 2 (dx_{i-1} + dx_i) s_i + dx_{i-1} s_{i+1} = 3 (dx_i m_{i-1} + dx_{i-1} m_i),
    with m_i the secant slopes, and at each end a continuous third derivative across the
    second knot (de Boor, *A Practical Guide to Splines*, 2001, ch. IV).
    """
    order = np.argsort(x)
    x = np.asarray(x, dtype=float)[order]
    y = np.asarray(y, dtype=float)[order]
    n = x.size
    if n < 4 or np.any(np.diff(x) <= 0.0):
        raise ValueError("a not-a-knot spline needs at least 4 strictly increasing abscissae")
    dx = np.diff(x)
    m = np.diff(y) / dx
    A = np.zeros((n, n))
    b = np.zeros(n)
    for i in range(1, n - 1):
        A[i, i - 1] = dx[i]
        A[i, i] = 2.0 * (dx[i - 1] + dx[i])
        A[i, i + 1] = dx[i - 1]
        b[i] = 3.0 * (dx[i] * m[i - 1] + dx[i - 1] * m[i])
    d = dx[0] + dx[1]
    A[0, 0], A[0, 1] = dx[1], d
    b[0] = ((dx[0] + 2.0 * d) * dx[1] * m[0] + dx[0] ** 2 * m[1]) / d
    d = dx[-1] + dx[-2]
    A[-1, -2], A[-1, -1] = d, dx[-2]
    b[-1] = (dx[-1] ** 2 * m[-2] + (2.0 * d + dx[-1]) * dx[-2] * m[-1]) / d
    s = np.linalg.solve(A, b)
    c2 = (3.0 * m - 2.0 * s[:-1] - s[1:]) / dx
    c3 = (s[:-1] + s[1:] - 2.0 * m) / dx**2

    def evaluate(xq):
        """The spline at xq (a number, or an array of them)."""
        q = np.asarray(xq, dtype=float)
        i = np.clip(np.searchsorted(x, q, side="right") - 1, 0, n - 2)
        t = q - x[i]
        out = y[i] + t * (s[i] + t * (c2[i] + t * c3[i]))
        return float(out) if out.ndim == 0 else out

    return evaluate


def rect_CA(ratio: float) -> float:
    """C_A of a 2-D rectangle for a/b (DNV-RP-H103 table A-1), not-a-knot spline."""
    t = dnv_tables()
    return float(_spline(t.rect_a_over_b, t.rect_CA)(ratio))


def rect_beta(ratio: float) -> float:
    """beta (added moment of inertia) of a 2-D rectangle for a/b (table A-1)."""
    t = dnv_tables()
    return float(_spline(t.rect_a_over_b, t.rect_beta)(ratio))


def prism_CA(ratio: float) -> float:
    """C_A of a square prism for b/a (table A-2)."""
    t = dnv_tables()
    return float(_spline(t.prism_b_over_a, t.prism_CA)(ratio))


@dataclass(frozen=True)
class AddedMassEstimate:
    """SNAME added-mass derivatives (negative) with the method's intermediate values."""

    X_udot: float  # [kg]
    Y_vdot: float  # [kg]
    Z_wdot: float  # [kg]
    N_rdot: float  # [kg m^2]
    c_xy: float
    c_yz: float
    c_xz: float
    scale: float  # lambda = sqrt(X_3 / X_s)
    surge_3d: float  # X_3 [kg] (magnitude)
    surge_strip: float  # X_s [kg] (magnitude)
    ratios: dict[str, float]  # table arguments: prism L/a, rect W/L, rect L/W
    coefficients: dict[str, float]  # interpolated table values
    extrapolated: tuple[str, ...]  # table arguments outside the tabulated range
    cross_section_mismatch: float  # |W - H| / max(W, H): Eidsvik's method assumes <= 0.10

    def as_dict(self) -> dict[str, Any]:
        return {
            "X_udot": self.X_udot, "Y_vdot": self.Y_vdot, "Z_wdot": self.Z_wdot, "N_rdot": self.N_rdot,
            "lambda": self.scale, "c_xy": self.c_xy, "c_yz": self.c_yz, "c_xz": self.c_xz,
            "ratios": dict(self.ratios), "coefficients": dict(self.coefficients),
            "extrapolated": list(self.extrapolated), "cross_section_mismatch": self.cross_section_mismatch,
        }

    def values(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ADDED_MASS_KEYS}


def added_mass_dnv(*, length: float, width: float, height: float, area_front: float, area_side: float,
                   area_top: float, rho: float = 1000.0) -> AddedMassEstimate:
    """Added mass of a box-shaped open-frame vehicle by Sandøy 2016, sec. 4.2.1 (inputs in m, m^2, kg/m^3)."""
    dims = {"length": length, "width": width, "height": height, "area_front": area_front,
            "area_side": area_side, "area_top": area_top, "rho": rho}
    bad = [f"{k} = {v!r}" for k, v in dims.items() if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0)]
    if bad:
        raise IdentificationError("added mass needs positive finite dimensions: " + ", ".join(bad))
    L, W, H = float(length), float(width), float(height)
    for name, area, box in (("area_front", area_front, H * W), ("area_side", area_side, L * H),
                            ("area_top", area_top, L * W)):
        if area > box * (1 + 1e-9):
            raise IdentificationError(f"{name} = {area:g} m^2 is larger than the box face it is projected on "
                                      f"({box:g} m^2); check the dimensions and the plane of each area")
    c_xy = area_top / (L * W)
    c_yz = area_front / (H * W)
    c_xz = area_side / (L * H)
    t = dnv_tables()
    a = (H + W) / 2.0
    ratios = {"prism_L_over_a": L / a, "rect_W_over_L": W / L, "rect_L_over_W": L / W}
    C3 = prism_CA(ratios["prism_L_over_a"])
    ca_wl = rect_CA(ratios["rect_W_over_L"])
    ca_lw = rect_CA(ratios["rect_L_over_W"])
    beta_wl = rect_beta(ratios["rect_W_over_L"])
    X3 = rho * C3 * a * a * L * c_yz**2 * c_xz * c_xy
    Xs = rho * ca_wl * math.pi * (W / 2) ** 2 * c_yz**2 * c_xz * c_xy * H
    if X3 <= 0 or Xs <= 0:
        raise IdentificationError(f"the DNV tables extrapolate to a non-positive coefficient for these "
                                  f"proportions (L/a = {ratios['prism_L_over_a']:.3g}, W/L = {W / L:.3g})")
    lam = math.sqrt(X3 / Xs)
    Y = lam * rho * ca_lw * math.pi * (L / 2) ** 2 * c_xz**2 * c_xy * c_yz * H
    Z = lam * rho * ca_lw * math.pi * (L / 2) ** 2 * c_xy**2 * c_xz * c_yz * W
    N = lam * rho * beta_wl * math.pi * (L / 2) ** 4 * c_yz * c_xy * c_xz * H
    extrap = []
    for key, lo, hi in (("prism_L_over_a", t.prism_b_over_a.min(), t.prism_b_over_a.max()),
                        ("rect_W_over_L", t.rect_a_over_b.min(), t.rect_a_over_b.max()),
                        ("rect_L_over_W", t.rect_a_over_b.min(), t.rect_a_over_b.max())):
        if not lo <= ratios[key] <= hi:
            extrap.append(f"{key} = {ratios[key]:.3g} outside {lo:g}..{hi:g}")
    return AddedMassEstimate(
        X_udot=-lam * Xs, Y_vdot=-Y, Z_wdot=-Z, N_rdot=-N, c_xy=c_xy, c_yz=c_yz, c_xz=c_xz, scale=lam,
        surge_3d=X3, surge_strip=Xs, ratios=ratios,
        coefficients={"prism_CA": C3, "rect_CA(W/L)": ca_wl, "rect_CA(L/W)": ca_lw, "rect_beta(W/L)": beta_wl},
        extrapolated=tuple(extrap), cross_section_mismatch=abs(W - H) / max(W, H))


def added_mass_from_vehicle(vehicle) -> AddedMassEstimate:
    """Sandøy 2016, sec. 4.2.1 on a vehicle's ``[geometry]`` block and water density."""
    g = vehicle.geometry
    if g is None:
        raise IdentificationError(f"vehicle {vehicle.name!r} has no [geometry] block (length, width, height, "
                                  "area_front, area_side, area_top)")
    return added_mass_dnv(length=g.length, width=g.width, height=g.height, area_front=g.area_front,
                          area_side=g.area_side, area_top=g.area_top, rho=vehicle.water_density)


def added_mass_edits(estimate: AddedMassEstimate, *, digits: int = 4) -> dict[str, float]:
    """Vehicle-file edits for ``[added_mass]``."""
    from rovlab.ident.fitting import significant

    return {f"added_mass.{k}": significant(getattr(estimate, k), digits) for k in ADDED_MASS_KEYS}
