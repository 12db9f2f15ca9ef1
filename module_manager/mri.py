"""The MRI types now live in :mod:`bbcs.contracts.mri`; this name is kept for code written against it."""

from bbcs.contracts.mri import *  # noqa: F403
