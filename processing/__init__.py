"""Pure numerical code of the scene-flow method (Rangel, Schmoll, Kroll, WACV 2020).

Nothing here imports :mod:`appliance` or :mod:`drivers`. Importing it points numba's
cache at a folder of this code version (:mod:`processing.kernel_cache`) before any
kernel is defined.
"""

from processing.kernel_cache import use_versioned_cache

use_versioned_cache()
