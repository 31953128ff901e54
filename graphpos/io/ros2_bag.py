"""Estimates out as a ROS 2 bag of ``nav_msgs/Odometry`` messages, written with ``rosbags``.

The bag is a rosbag2 folder (``metadata.yaml`` and one MCAP file,
zstd-compressed chunks, bag format version 8) that ``ros2 bag info|play``
(Jazzy and later), Foxglove, rosbags' readers and evo (``evo_traj bag2
FOLDER --all_topics``, ``evo_ape bag2 FOLDER /graphpos/truth/odometry
/graphpos/graph_batch/odometry``) read. No ROS install is needed to write
it.

One topic per estimate, ``/graphpos/<name>/odometry``, where ``<name>`` is
the estimate's name with every character a ROS name does not allow (``-``
among them) as ``_`` (``graph-batch`` -> ``/graphpos/graph_batch/odometry``;
the bag's ``custom_data`` key ``graphpos.estimators`` maps each topic back
to its estimator's name). Each output epoch is one message:

- ``header.stamp``: the epoch ``t_s`` (whole seconds and nanoseconds);
  ``header.frame_id`` ``map`` (the drive's local east-north frame: x east,
  y north, z up), ``child_frame_id`` ``base_link`` (x forward, y left);
- ``pose.pose``: east, north, 0 and the yaw as a rotation about z (the
  identity where the estimator gives no yaw, as in the TUM export);
- ``pose.covariance`` (row-major 6 x 6 over x, y, z, roll, pitch, yaw): the
  east/north covariance in its top-left 2 x 2 block and zeros elsewhere;
  all zeros (ROS: unknown) where the estimator gives none;
- ``twist.twist.linear``: the velocity in ``base_link`` (forward, left,
  0), as REP 105 and ``nav_msgs/Odometry`` put it, turned by the same yaw
  as the pose; NaN where the estimator gives no velocity.
  ``twist.twist.angular`` is NaN (no estimator gives a yaw rate) and
  ``twist.covariance`` all zeros (unknown).

The record time of a message is its stamp in nanoseconds (clipped at 0: a
bag has no negative record times); messages are written in time order
across topics.

The messages of an estimate are encoded together in one array in CDR
(little-endian), byte for byte what rosbags' serializer gives for each
(every ``nav_msgs/Odometry`` with these frame names has the same layout);
rosbags writes the bag.
"""

from __future__ import annotations

import heapq
import json
import os
import re
from itertools import repeat
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from graphpos.estimate import Estimate

#: Frame of the poses (the drive's local east-north-up frame) and of the vehicle.
MAP_FRAME, BODY_FRAME = "map", "base_link"
#: Message type of every topic.
ODOMETRY = "nav_msgs/msg/Odometry"
#: rosbag2 format version written (8: ROS 2 Jazzy).
BAG_VERSION = 8


def odometry_topic(name: str) -> str:
    """The topic of the estimate ``name``: ``/graphpos/<name>/odometry``, ``<name>`` made a ROS name token."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not token or token[0].isdigit():
        token = f"_{token}"
    return f"/graphpos/{token}/odometry"


def _topics(estimates: Sequence[Estimate]) -> list[str]:
    """One topic per estimate; a name that makes the topic of an earlier one gets ``_2``, ``_3`` ..."""
    topics: list[str] = []
    for est in estimates:
        base = topic = odometry_topic(est.name)
        copy = 1
        while topic in topics:
            copy += 1
            topic = base.replace("/odometry", f"_{copy}/odometry")
        topics.append(topic)
    return topics


#: One ``nav_msgs/Odometry`` message in little-endian CDR: every message has
#: the same 716 bytes of layout, the frame names being fixed.
_ODOMETRY_CDR = np.dtype({
    "names": ["encapsulation", "sec", "nanosec", "frame_ids", "pose", "pose_covariance", "twist", "twist_covariance"],
    "formats": ["V4", "<i4", "<u4", "V24", ("<f8", 7), ("<f8", 36), ("<f8", 6), ("<f8", 36)],
    "offsets": [0, 4, 8, 12, 36, 92, 380, 428],
    "itemsize": 716,
})
#: Messages encoded at a time (an hour's truth at once would take 0.8 GB).
_BATCH_MESSAGES = 20_000
#: The CDR header (little-endian), and the frame ids as CDR strings (a length counting the NUL, the text, the NUL), padded
#: to the 8-byte alignment of the pose that follows.
_CDR_LE = b"\x00\x01\x00\x00"
_FRAME_IDS = b"".join(len(f).to_bytes(4, "little") + f for f in (MAP_FRAME.encode() + b"\0", BODY_FRAME.encode() + b"\0")).ljust(24, b"\0")


def _messages(est: Estimate) -> Iterator[tuple[int, bytes]]:
    """(record time in ns, CDR bytes) of each output epoch of ``est`` (module
    docstring), encoded :data:`_BATCH_MESSAGES` at a time in one array."""
    n = len(est)
    yaw = np.zeros(n) if est.yaw_rad is None else np.nan_to_num(est.yaw_rad)
    cos, sin = np.cos(yaw), np.sin(yaw)
    if est.has_velocity:
        forward = est.v_east_mps * cos + est.v_north_mps * sin
        left = -est.v_east_mps * sin + est.v_north_mps * cos
    else:
        forward = left = np.full(n, np.nan)
    whole = np.floor(est.t_s)
    nanos = np.round((est.t_s - whole) * 1e9).astype(np.int64)
    sec = whole.astype(np.int64) + nanos // 1_000_000_000
    nanos %= 1_000_000_000
    record_ns = np.maximum(sec * 1_000_000_000 + nanos, 0)
    size = _ODOMETRY_CDR.itemsize
    for first in range(0, n, _BATCH_MESSAGES):
        rows = slice(first, first + _BATCH_MESSAGES)
        cdr = np.zeros(len(record_ns[rows]), dtype=_ODOMETRY_CDR)
        cdr["encapsulation"], cdr["frame_ids"] = np.void(_CDR_LE), np.void(_FRAME_IDS)
        cdr["sec"], cdr["nanosec"] = sec[rows], nanos[rows]
        cdr["pose"][:, 0], cdr["pose"][:, 1] = est.east_m[rows], est.north_m[rows]
        cdr["pose"][:, 5], cdr["pose"][:, 6] = np.sin(yaw[rows] / 2), np.cos(yaw[rows] / 2)
        if est.cov_en_m2 is not None:
            cdr["pose_covariance"].reshape(-1, 6, 6)[:, :2, :2] = est.cov_en_m2[rows]
        cdr["twist"][:, 0], cdr["twist"][:, 1], cdr["twist"][:, 3:] = forward[rows], left[rows], np.nan
        data = cdr.tobytes()
        yield from zip(record_ns[rows].tolist(), [data[k : k + size] for k in range(0, len(data), size)])


def write_odometry_bag(path: str | os.PathLike, estimates: Sequence[Estimate]) -> Path:
    """Write ``estimates`` as a ROS 2 bag folder of ``nav_msgs/Odometry`` (module docstring).

    Parameters
    ----------
    path : path-like
        The bag folder to create; it must not exist. Written in place: a
        command writes it inside its output folder
        (:func:`graphpos.io.outputs.output_folder`), which appears whole or
        not at all.
    estimates : sequence of Estimate

    Returns
    -------
    Path
        The bag folder.
    """
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    topics = _topics(estimates)
    writer = Writer(path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    writer.set_custom_data("graphpos.estimators", json.dumps({t: e.name for t, e in zip(topics, estimates)}))
    with writer:
        connections = [writer.add_connection(topic, ODOMETRY, typestore=typestore) for topic in topics]
        streams = [zip(repeat(connection), _messages(est)) for connection, est in zip(connections, estimates)]
        for connection, (ns, data) in heapq.merge(*streams, key=lambda message: message[1][0]):
            writer.write(connection, ns, data)
    return path
