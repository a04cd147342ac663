"""Resource package: the usd-gs codeless USD schema (``plugInfo.json``, ``generatedSchema.usda``,
``schema.usda``). Installed as ``usd_gs.schemas``; registered by ``usd_gs.usd.schema.register_plugins``."""
