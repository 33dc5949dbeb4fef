"""An estimator and a controller for rovlab, from outside it (docs/architecture.md walks through them).

* ``complementary``: a complementary depth-and-heading filter (rovlab_example_plugin.complementary);
* ``pd``: a PD depth-and-heading law with the net buoyancy fed forward (rovlab_example_plugin.pd).

Installed, they are found through the entry points in pyproject.toml: no line of rovlab changes.
"""

from pathlib import Path

EXAMPLES = Path(__file__).parent  # the example scenario and configuration beside this file
