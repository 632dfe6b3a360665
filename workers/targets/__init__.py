"""Targets under the sea: what each renderer needs of a target's shape.

Every module here is imported with the package, so a shape registered in its own module
(`workers.targets.base.register`) is a choice of ``target.shape`` for both renderers.
"""

import importlib
import pkgutil

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
