"""Parser for the CROMAT .conf format (SPEC §4, seed 004 §5.2.2.1), with line-numbered errors.

``key: value`` / ``key = value`` entries and ``Type: name { ... }`` groups, in any order, with ``#`` comments;
values stay text until ``to_struct`` types them through a msgspec Struct. See docs/conf_format.md.
"""

from bbcs.conf.errors import ConfError
from bbcs.conf.model import ConfDocument, ConfEntry, ConfGroup
from bbcs.conf.parser import load_conf, parse_conf

__all__ = ["ConfDocument", "ConfEntry", "ConfError", "ConfGroup", "load_conf", "parse_conf"]
