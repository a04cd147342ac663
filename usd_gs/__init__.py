"""usd-gs: consistent lighting and shadows for animated 3D Gaussian Splat avatars in USD."""

__version__ = "0.1.0"

from usd_gs.gaussians import GaussianSet  # noqa: E402
from usd_gs.usd.schema import register_plugins as _register_plugins  # noqa: E402

_register_plugins()

__all__ = ["GaussianSet", "__version__"]
