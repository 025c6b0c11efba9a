"""Bags: record, replay, inspect, convert and recover topic recordings as MCAP files.

See FORMAT.md in this folder for the byte layout (readable from any language) and
:mod:`.writer`, :mod:`.reader`, :mod:`.player`, :mod:`.recover`, :mod:`.convert`.
"""
from .errors import BagError
from .framing import MESSAGE_ENCODING, pack_frames, unpack_frames
from .reader import BagReader, BagSummary, RawMessage, TopicInfo, check_bag_file
from .recover import RecoveryReport, recover
from .writer import BagWriter, base_metadata

__all__ = ["BagError", "BagReader", "BagSummary", "BagWriter", "MESSAGE_ENCODING", "RawMessage",
           "RecoveryReport", "TopicInfo", "base_metadata", "check_bag_file", "pack_frames", "recover",
           "unpack_frames"]
