"""The GRI types now live in :mod:`bbcs.contracts.gri`; this name is kept for code written against ``ral.gri``."""

from bbcs.contracts.gri import *  # noqa: F403
from bbcs.contracts.gri import __all__  # noqa: F401
