"""metadata.yaml while a bag is written: there from the start, marked unfinished until the writer closes.

rosbags writes a bag's ``metadata.yaml`` only when it closes the bag, so a writer killed
mid-recording used to leave a directory no reader recognises. :func:`write_unfinished`
writes it when the bag opens (and again for each new topic), in rosbag2's own format with
``custom_data: {elastic_pm_dyn.recording: unfinished}``; closing the bag replaces it with
rosbags' complete one, without the mark. :func:`recording_state` reads the mark back, so
that a reader tells a recording that was cut off (its data recovered, with a warning) from
a finished bag that was damaged afterwards (an error).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.metadata import dump_qos_v8, dump_qos_v9

MARK = "elastic_pm_dyn.recording"
UNFINISHED = "unfinished"


def write_unfinished(w: Writer) -> None:
    """``metadata.yaml`` of the open bag ``w``: its storage file and topics, no messages yet, marked unfinished."""
    assert w.storage is not None
    dump_qos = dump_qos_v9 if w.version >= 9 else dump_qos_v8
    name = w.storage.path.name
    info: dict[str, Any] = {
        "version": w.version,
        "storage_identifier": w.storage_plugin.name.lower(),
        "relative_file_paths": [name],
        "duration": {"nanoseconds": 0},
        "starting_time": {"nanoseconds_since_epoch": 0},
        "message_count": 0,
        "topics_with_message_count": [
            {"topic_metadata": {"name": c.topic, "type": c.msgtype, "serialization_format": c.ext.serialization_format,
                                "offered_qos_profiles": dump_qos(c.ext.offered_qos_profiles),
                                "type_description_hash": c.digest},
             "message_count": 0}
            for c in w.connections],
        "compression_format": "",
        "compression_mode": "",
        "files": [{"path": name, "starting_time": {"nanoseconds_since_epoch": 0}, "duration": {"nanoseconds": 0},
                   "message_count": 0}],
        "custom_data": {MARK: UNFINISHED},
        "ros_distro": "rosbags",
    }
    tmp = w.metapath.with_suffix(".yaml.tmp")  # replaced at once: never a half-written file
    tmp.write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}, default_flow_style=False), "utf8")
    tmp.replace(w.metapath)


def recording_state(bag_dir: Path) -> str | None:
    """'unfinished' (a writer has not closed the bag), 'finished', or None (no readable metadata.yaml)."""
    try:
        info = yaml.load((bag_dir / "metadata.yaml").read_text("utf8"), Loader=_LOADER)
        info = info["rosbag2_bagfile_information"]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, TypeError, KeyError):
        return None
    if not isinstance(info, dict):
        return None
    custom = info.get("custom_data")
    return UNFINISHED if isinstance(custom, dict) and custom.get(MARK) == UNFINISHED else "finished"


_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
