"""Loading what a vehicle node or a simulated vehicle runs, the same for every middleware."""

from __future__ import annotations

from rovlab.interfaces.node.core import NodeCore
from rovlab.interfaces.node.ros_common import ParameterTable
from rovlab.sim.realtime import SimulatedVehicle


def load_node(vehicle: str, config: str, **core_options: object) -> tuple[NodeCore, ParameterTable]:
    """The node core for a vehicle and a configuration (names or TOML files) and its run-time
    parameter table; ConfigError naming the file and the field for anything wrong."""
    from rovlab.params.design import design_config_from_dict, resolve_config_path
    from rovlab.params.validate import read_toml
    from rovlab.params.vehicle import load_vehicle

    v = load_vehicle(vehicle)
    path = resolve_config_path(config)
    data = read_toml(path)
    cfg = design_config_from_dict(data, file=str(path))
    core = NodeCore(v, cfg, **core_options)  # type: ignore[arg-type]
    return core, ParameterTable(core, path, data)


def load_sim(scenario: str, vehicle: str | None = None, seed: int | None = None) -> SimulatedVehicle:
    """A scenario's simulated vehicle; ``vehicle`` replaces the scenario's (model and truth)."""
    from rovlab.params.vehicle import load_vehicle

    v = load_vehicle(vehicle) if vehicle else None
    return SimulatedVehicle(scenario, seed=seed, vehicle=v)
