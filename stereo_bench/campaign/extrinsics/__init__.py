"""One strategy object per extrinsics source (``[extrinsics] mode``): :class:`ExtrinsicsSource` in :mod:`.base`.

    source = config.extrinsics.source()           # or extrinsics_source("kinematic")
    source.visit_purpose(config.extrinsics)       # "kinematic" (the design), "intrinsics" (nominal) or None
    analysis, used = source.analyse(options, prepared, captured, calibrate=...)

Every module of this package but :mod:`.base` defines one source and is imported here, so a source registers
itself in :data:`SOURCES` by being a module of the package. Adding a source: its module here, and its name in
``ExtrinsicsSection.mode`` (``tests/test_extrinsics_registry.py`` checks that the two agree).
"""

from importlib import import_module
from pkgutil import iter_modules

from stereo_bench.campaign.extrinsics.base import SOURCES, ExtrinsicsSource, extrinsics_source

for _module in iter_modules(__path__):
    if _module.name != "base":
        import_module(f"{__name__}.{_module.name}")

__all__ = ["SOURCES", "ExtrinsicsSource", "extrinsics_source"]
