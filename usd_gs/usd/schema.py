"""The usd-gs role schema: a codeless single-apply API schema ``UsdGsRoleAPI``.

The schema files live in the repository's ``schemas/`` directory, installed as the
package ``usd_gs.schemas`` (``plugInfo.json``, ``generatedSchema.usda``, ``schema.usda``).
``import usd_gs`` makes them known to ``Plug`` (:func:`usd_gs.usd.plugin_path.register_at_import`:
``PXR_PLUGINPATH_NAME`` before pxr is loaded, else :func:`register_plugins`).

Properties (all ``uniform``, never time-sampled):

- ``usdgs:role`` token, one of ``auto`` (default), ``scene``, ``avatar``, ``object``.
- ``usdgs:castsShadows`` bool, default true: the prim's Gaussians occlude light for others.
- ``usdgs:receivesShadows`` bool, default true: shadows of other prims darken this prim
  (applies to avatars and objects; a captured scene already carries its baked shadows).
- ``usdgs:relight`` bool, default true: rewrite this prim's SH to match the scene lighting
  (applies to avatars and objects; a scene defines the lighting and is never relit).

Registration caveat (OpenUSD behaviour, not ours): ``UsdSchemaRegistry`` is built once, the
first time any stage or schema query needs it. A schema registered after that is not seen
in that process. ``import usd_gs`` before using USD, or set ``PXR_PLUGINPATH_NAME`` to
:func:`schema_dir`. Reading and applying roles still works without the registered schema:
:func:`read_role` reads the attributes by name, :func:`apply_role` records the API name in
``apiSchemas`` and authors the attributes with their schema types.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from usd_gs.errors import UserError
from usd_gs.usd.plugin_path import PLUGIN_NAME, missing_schema_error, schema_folder

ROLE_API = "UsdGsRoleAPI"
"""Schema identifier (the name in ``apiSchemas``). Its TfType name is ``UsdGsUsdGsRoleAPI``
(usdGenSchema's library prefix ``UsdGs`` + class name; a TfType may not alias its own name)."""
ROLES = ("auto", "scene", "avatar", "object")

ATTR_ROLE = "usdgs:role"
ATTR_CASTS_SHADOWS = "usdgs:castsShadows"
ATTR_RECEIVES_SHADOWS = "usdgs:receivesShadows"
ATTR_RELIGHT = "usdgs:relight"

#: fallback values, identical to those in schemas/generatedSchema.usda
FALLBACKS = {ATTR_ROLE: "auto", ATTR_CASTS_SHADOWS: True, ATTR_RECEIVES_SHADOWS: True, ATTR_RELIGHT: True}

_registered: bool = False


@dataclass(frozen=True)
class RoleInfo:
    """Resolved role of one prim.

    ``role`` is one of :data:`ROLES`; the booleans are the authored values or the schema
    fallbacks (all true). ``applied`` says whether ``UsdGsRoleAPI`` is in the prim's
    ``apiSchemas``; attributes authored without the API applied still count.
    """

    role: str = "auto"
    casts_shadows: bool = True
    receives_shadows: bool = True
    relight: bool = True
    applied: bool = False


def schema_dir() -> Path:
    """Directory holding ``plugInfo.json`` of the usd-gs schema plugin
    (:func:`usd_gs.usd.plugin_path.schema_folder`); ``UserError`` when it is absent."""
    folder = schema_folder()
    if folder is None:
        raise missing_schema_error()
    return Path(folder)


def register_plugins() -> bool:
    """Register the usd-gs schema plugin with ``Plug`` (idempotent, about 1 ms).

    Returns True when the plugin is registered (now or before, possibly by
    ``PXR_PLUGINPATH_NAME``). Must run before the first stage is opened for the
    ``UsdGsRoleAPI`` prim definition to exist in this process (see module docstring).
    """
    global _registered
    if _registered:
        return True
    from pxr import Plug

    reg = Plug.Registry()
    if reg.GetPluginWithName(PLUGIN_NAME) is None:
        reg.RegisterPlugins(str(schema_dir()))
    _registered = reg.GetPluginWithName(PLUGIN_NAME) is not None
    return _registered


def schema_available() -> bool:
    """True when ``UsdGsRoleAPI`` has a prim definition in this process's schema registry."""
    register_plugins()
    from pxr import Usd

    return Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(ROLE_API) is not None


def _sdf_types():
    from pxr import Sdf

    return {ATTR_ROLE: Sdf.ValueTypeNames.Token, ATTR_CASTS_SHADOWS: Sdf.ValueTypeNames.Bool,
            ATTR_RECEIVES_SHADOWS: Sdf.ValueTypeNames.Bool, ATTR_RELIGHT: Sdf.ValueTypeNames.Bool}


def apply_role(prim, role: str, casts_shadows: bool | None = None, receives_shadows: bool | None = None,
               relight: bool | None = None) -> RoleInfo:
    """Apply ``UsdGsRoleAPI`` to ``prim`` and author ``usdgs:role`` (always) and the given flags.

    Flags left as None are not authored (the schema fallback, true, applies). Raises
    ``UserError`` naming the prim for an unknown role or an invalid prim. Works in the
    current edit target (an output layer authors ``over`` specs). Returns :func:`read_role`.
    """
    from pxr import Sdf, Usd

    if prim is None or not prim.IsValid():
        raise UserError(f"cannot apply {ROLE_API}: invalid prim {prim}")
    path = prim.GetPath()
    if role not in ROLES:
        raise UserError(f"{path}: role '{role}' is not one of {', '.join(ROLES)}")
    register_plugins()
    if Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(ROLE_API) is not None:
        if not prim.ApplyAPI(ROLE_API):
            raise UserError(f"{path}: cannot apply {ROLE_API}")
    else:  # schema registry was built before registration: record the API name directly
        prim.AddAppliedSchema(ROLE_API)
    types = _sdf_types()
    values = {ATTR_ROLE: role, ATTR_CASTS_SHADOWS: casts_shadows, ATTR_RECEIVES_SHADOWS: receives_shadows,
              ATTR_RELIGHT: relight}
    for name, value in values.items():
        if value is None:
            continue
        attr = prim.CreateAttribute(name, types[name], False, Sdf.VariabilityUniform)
        attr.Set(value if name == ATTR_ROLE else bool(value))
    return read_role(prim)


def read_role(prim) -> RoleInfo:
    """Role of ``prim`` from its ``usdgs:*`` attributes (fallbacks where unauthored).

    Works whether or not ``UsdGsRoleAPI`` is applied or registered. A ``usdgs:role`` value
    outside :data:`ROLES` raises ``UserError`` naming the prim and attribute.
    """
    from pxr import Usd

    out = {}
    for name, fallback in FALLBACKS.items():
        attr = prim.GetAttribute(name)
        value = attr.Get(Usd.TimeCode.Default()) if attr and attr.HasValue() else None
        out[name] = fallback if value is None else value
    role = str(out[ATTR_ROLE])
    if role not in ROLES:
        raise UserError(f"{prim.GetPath()}: attribute '{ATTR_ROLE}' has value '{role}', not one of {', '.join(ROLES)}")
    applied = ROLE_API in prim.GetAppliedSchemas() or _listed_in_api_schemas(prim)
    return RoleInfo(role, bool(out[ATTR_CASTS_SHADOWS]), bool(out[ATTR_RECEIVES_SHADOWS]), bool(out[ATTR_RELIGHT]),
                    applied)


def _listed_in_api_schemas(prim) -> bool:
    """True if ``apiSchemas`` metadata names the API (needed when the schema is unregistered:
    ``GetAppliedSchemas`` drops names without a prim definition)."""
    op = prim.GetMetadata("apiSchemas")
    if not op:
        return False
    return ROLE_API in op.ApplyOperations([])
