"""Names of error codes by source module (docs/error_codes.md), for tools that show errors to people.

The codes and the table ``module → enum`` are part of the bus contract and live in
:mod:`bbcs.contracts.error_codes`; this module is the tools' entry point to them. An unknown code has no name
(``""``), so a tool shows its number.
"""

from __future__ import annotations

from bbcs.contracts.error_codes import MODULE_CODES
from bbcs.contracts.error_codes import error_name as _contract_error_name

__all__ = ["MODULE_CODES", "error_name"]


def error_name(source: str, code: int) -> str:
    """``OUT_OF_RANGE``, ``SPEED_ABOVE_MAX``, ``DSP_WRONG_MODE``... or ``""`` when the code is not known."""
    return _contract_error_name(source, code)
