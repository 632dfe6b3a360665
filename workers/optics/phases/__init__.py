"""Phase functions of sea water as plug-ins: one module each, registered by name.

Every module here is imported with the package, so a function registered in its own module
(`workers.optics.phases.base.register`) is a choice of ``water.phase_function`` and, if it
is defined over the whole sphere, of ``transport.phase_function``.
"""

import importlib
import pkgutil

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
