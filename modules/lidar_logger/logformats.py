"""Which reader a log path takes: a text log, a binary log (either of its two files), or a run folder.

Apart from :mod:`modules.lidar_logger.logdata` (the in-memory model both readers fill) so that the model does not
import the formats that import it.
"""

from __future__ import annotations

import os
from pathlib import Path

from modules.lidar_logger import binlog, textlog
from modules.lidar_logger.logdata import LidarLog, LogFormatError


def load_log(path: str | os.PathLike[str]) -> LidarLog:
    """Load a text log, a binary log (either of its two files), or a run folder (binary preferred)."""
    p = Path(path)
    if p.is_dir():
        bins = sorted(p.glob(f"*{binlog.SCANS_SUFFIX}"))
        if bins:
            return binlog.read_binary_log(bins[0])
        texts = sorted(q for q in p.glob("LogFile_*") if q.is_file() and not q.name.endswith(".bin"))
        if texts:
            return textlog.read_text_log(texts[0])
        raise LogFormatError(f"{p}: no LogFile_* in this folder")
    if p.name.endswith(binlog.SCANS_SUFFIX) or p.name.endswith(binlog.POINTS_SUFFIX):
        return binlog.read_binary_log(p)
    return textlog.read_text_log(p)
