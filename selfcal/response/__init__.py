"""The JPEG-only path: a camera's response from an exposure stack ([Lin2011] §5).

:func:`selfcal.calibrate_response` (:mod:`.calibrate`) takes its finer settings as a
:class:`ResponseOptions`; the solve of Eq. 8 alone (:mod:`.solver`) as a
:class:`SolverOptions`.
"""

from .calibrate import ResponseOptions
from .solver import SolverOptions

__all__ = ["ResponseOptions", "SolverOptions"]
