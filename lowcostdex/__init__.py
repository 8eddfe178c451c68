"""lowcostdex: learn dexterous skills on low-cost robot hands in the real world.

Subpackages:
  hardware  motor buses (Dynamixel, Allegro CAN), emulated devices, hand specs, the safe Robot.
  sim       MJCF models, the shared servo/effect model, gymnasium tasks, batched stepping, gap analysis.
  algos     policies, NPG, DAPG, BC, samplers, learned local models.

Module ``demo_file``: the demonstration dataset (HDF5) every recorder writes and BC/DAPG read.

Importing the package registers the gymnasium environments (ids ``lowcostdex/...``).
"""

__version__ = "0.1.0"

from lowcostdex.sim import registry as _registry  # noqa: E402

_registry.register_envs()
