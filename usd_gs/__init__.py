"""usd-gs: consistent lighting and shadows for animated 3D Gaussian Splat avatars in USD.

Importing the package loads neither numpy nor pxr (``GaussianSet`` is imported on first use);
it makes the schema plugin known to USD (:func:`usd_gs.usd.plugin_path.register_at_import`).
"""

__version__ = "0.1.0"

from usd_gs._lazy import lazy_exports  # noqa: E402
from usd_gs.usd.plugin_path import register_at_import as _register_at_import  # noqa: E402

_register_at_import()

__getattr__, __dir__, _exports = lazy_exports("usd_gs", {"GaussianSet": "gaussians"})
__all__ = ["GaussianSet", "__version__"]
