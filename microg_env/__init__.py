"""microg: MuJoCo model of the QZS microgravity landing rig of Jia et al., Actuators 2024, 13(9), 361."""

from microg_env.contact import SpringDamperContact
from microg_env.drop import drop_test, static_sink
from microg_env.model import PadTest, Rig, build_pad_test, build_rig
from microg_env.params import RigParams

__version__ = "0.1.0"

__all__ = [
    "PadTest",
    "Rig",
    "RigParams",
    "SpringDamperContact",
    "__version__",
    "build_pad_test",
    "build_rig",
    "drop_test",
    "static_sink",
]
