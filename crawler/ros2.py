"""ROS 2 without ROS: nav_msgs/msg/Odometry as rmw_zenoh puts it on the wire, so ROS 2 sees the crawler.

A ROS 2 machine running rmw_zenoh_cpp (Jazzy, Humble and later) finds a topic by liveliness tokens
and reads its samples from one key expression; both are built here the way rmw_zenoh builds them
(ros2/rmw_zenoh: liveliness_utils.cpp, attachment_helpers.cpp, rmw_publisher_data.cpp, qos.cpp):

  data      <domain>/<topic without the leading />/nav_msgs::msg::dds_::Odometry_/<type hash>
  node      @ros2_lv/<domain>/<zid>/<node id>/<node id>/NN/<enclave>/<namespace>/<node>
  publisher @ros2_lv/<domain>/<zid>/<node id>/<pub id>/MP/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>

where names in tokens have every `/` replaced by `%`, the zid is the zenoh session id as zenoh prints
it, and the type hash is RIHS01_<sha256> (Jazzy and later) or `TypeHashNotSupported` (Humble). The
payload is CDR (XCDR1, little endian, 4-byte encapsulation header 00 01 00 00); each sample carries
a 33-byte attachment: sequence number (int64 LE, from 1), source timestamp (int64 LE, ns since the
epoch, the system clock at publication), then the GID as a zenoh-ext sequence (length 16 as a LEB128
byte, then 16 bytes): the XXH3-128 hash of the publisher's token, low 64 bits first, little endian.

Everything above is pure; Ros2Odometry declares the publisher and both tokens on a zenoh session the
caller owns, and publish() sends one message.
"""

from __future__ import annotations

import math
import re
import struct
import time

from .errors import BadConfig, CrawlerError
from .ports import Output

TYPE_NAME = "nav_msgs::msg::dds_::Odometry_"
# rosidl's RIHS01 hash of nav_msgs/msg/Odometry; the same in Jazzy, Kilted and Rolling. Humble's
# rmw_zenoh has no type hashes and puts this constant in their place.
TYPE_HASHES = {"jazzy": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
               "humble": "TypeHashNotSupported"}
ADMIN_SPACE = "@ros2_lv"
ENCLAVE = "/"
NODE_NAME = "crawlerd"
GID_SIZE = 16
# Variance of what a crawler does not measure (y, z, the orientation): large, so a fusion filter
# (robot_localization and the like) gives it no weight; REP 105 leaves it to the sender.
UNKNOWN_VARIANCE = 1e6
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_RELIABILITY = {"reliable": "", "best_effort": "2"}        # rmw_zenoh's default (reliable) is written empty


class Ros2Unavailable(CrawlerError, ImportError):
    """The ROS 2 publisher needs the xxhash package (rmw_zenoh's GIDs are XXH3-128 hashes)."""


# -- names ------------------------------------------------------------------------------------------

def ros_name(crawler_name: str) -> str:
    """A crawler name as a ROS name token: `-` is not allowed there, nor a leading digit."""
    token = crawler_name.replace("-", "_")
    return "c" + token if token[:1].isdigit() else token


def fully_qualified(topic: str, namespace: str) -> str:
    """`odom` in namespace `/crawler1` -> `/crawler1/odom`; an absolute topic stays as it is."""
    name = topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"
    tokens = name[1:].split("/")
    if not topic or topic.endswith("/") or not all(_TOKEN.match(t) for t in tokens):
        raise BadConfig(f"[ros2] topic = {topic!r} is not a ROS 2 topic name: tokens of letters, digits and _ "
                        "separated by /, none starting with a digit (e.g. /crawler1/odom)")
    return name


def mangle(name: str) -> str:
    """rmw_zenoh's mangling of a name inside a liveliness token: every `/` becomes `%`."""
    return name.replace("/", "%")


def qos_keyexpr(depth: int = 10, reliability: str = "reliable") -> str:
    """The QoS part of a token: KEEP_LAST `depth`, VOLATILE, no deadline, lifespan or lease.

    rmw_zenoh writes a policy only where it differs from its own default (reliable, volatile,
    keep last 42, infinite durations): `reliability:durability:history,depth:deadline s,ns:lifespan
    s,ns:liveliness,lease s,lease ns`.
    """
    if reliability not in _RELIABILITY:
        raise BadConfig(f"[ros2] reliability = {reliability!r}: reliable or best_effort")
    if not 1 <= depth <= 10_000:
        raise BadConfig(f"[ros2] depth = {depth!r}: a history depth of 1..10000")
    return f"{_RELIABILITY[reliability]}::,{'' if depth == 42 else depth}:,:,:,,"


def topic_keyexpr(domain_id: int, topic: str, type_hash: str) -> str:
    """The key expression the samples are put on: the topic without its leading (and trailing) slash."""
    return f"{domain_id}/{topic.strip('/')}/{TYPE_NAME}/{type_hash}"


def node_token(domain_id: int, zid: str, node_id: int, namespace: str, node: str = NODE_NAME) -> str:
    return "/".join([ADMIN_SPACE, str(domain_id), zid, str(node_id), str(node_id), "NN", mangle(ENCLAVE),
                     mangle(namespace), mangle(node)])


def publisher_token(domain_id: int, zid: str, node_id: int, pub_id: int, namespace: str, topic: str,
                    type_hash: str, qos: str, node: str = NODE_NAME) -> str:
    return "/".join([ADMIN_SPACE, str(domain_id), zid, str(node_id), str(pub_id), "MP", mangle(ENCLAVE),
                     mangle(namespace), mangle(node), mangle(topic), mangle(TYPE_NAME), mangle(type_hash), qos])


def gid(token: str) -> bytes:
    """The entity's GID as rmw_zenoh computes it: XXH3-128 of its token, low then high 64 bits (LE)."""
    try:
        import xxhash
    except ImportError:
        raise Ros2Unavailable("[ros2] needs the xxhash package: sudo apt install python3-xxhash on the Pi "
                              "(a venv made with --system-site-packages sees it), or pip install xxhash") from None
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


def attachment(sequence_number: int, source_timestamp_ns: int, source_gid: bytes) -> bytes:
    """rmw_zenoh's attachment: two int64 LE, then the GID as a zenoh-ext sequence (LEB128 length)."""
    if len(source_gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(source_gid)}")
    return struct.pack("<qqB", sequence_number, source_timestamp_ns, GID_SIZE) + bytes(source_gid)


# -- the message ------------------------------------------------------------------------------------

class _Cdr:
    """Little-endian XCDR1 after the encapsulation header: every primitive aligned to its size."""

    def __init__(self):
        self.buf = bytearray(b"\x00\x01\x00\x00")

    def _align(self, n: int):
        self.buf += b"\x00" * (-(len(self.buf) - 4) % n)

    def put(self, fmt: str, *values):
        self._align(struct.calcsize("<" + fmt[-1]))     # "7d": aligned as one double
        self.buf += struct.pack("<" + fmt, *values)

    def string(self, text: str):
        raw = text.encode() + b"\x00"
        self.put("I", len(raw))
        self.buf += raw


def stamp(t_ns: int) -> tuple[int, int]:
    """builtin_interfaces/Time: whole seconds (int32) and the nanoseconds 0..999999999 after them."""
    sec, nanosec = divmod(int(t_ns), 1_000_000_000)
    if not -2**31 <= sec < 2**31:
        raise ValueError(f"stamp {t_ns} ns does not fit builtin_interfaces/Time")
    return sec, nanosec


def covariance(sigma: float | None) -> list[float]:
    """6x6 row-major: sigma^2 for x, UNKNOWN_VARIANCE on the rest of the diagonal, 0 elsewhere."""
    cov = [0.0] * 36
    for i in range(6):
        cov[i * 7] = UNKNOWN_VARIANCE
    if sigma is not None:
        cov[0] = float(sigma) ** 2
    return cov


def odometry_cdr(stamp_ns: int, distance_m: float, speed_m_s: float | None, sigma_m: float | None,
                 sigma_speed: float | None, frame_id: str, child_frame_id: str) -> bytes:
    """nav_msgs/msg/Odometry: x along the pipe in `frame_id`, the speed along it in `child_frame_id`.

    A speed of None (tracking lost) is sent as 0 with the unknown variance; sigmas of None likewise.
    """
    for label, v in (("distance_m", distance_m), ("speed_m_s", speed_m_s), ("sigma_m", sigma_m),
                     ("sigma_speed", sigma_speed)):
        if v is not None and not math.isfinite(v):
            raise ValueError(f"{label} = {v!r}: only finite numbers are published")
    if speed_m_s is None:
        sigma_speed = None
    c = _Cdr()
    c.put("iI", *stamp(stamp_ns))
    c.string(frame_id)
    c.string(child_frame_id)
    c.put("7d", float(distance_m), 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)      # position, orientation (identity)
    c.put("36d", *covariance(sigma_m))
    c.put("6d", float(speed_m_s or 0.0), 0.0, 0.0, 0.0, 0.0, 0.0)      # linear, angular
    c.put("36d", *covariance(sigma_speed))
    return bytes(c.buf)


# -- on a zenoh session -----------------------------------------------------------------------------

class Ros2Odometry:
    """A ROS 2 node `/<name>/crawlerd` with one publisher of nav_msgs/msg/Odometry, on `session`."""

    NODE_ID, PUBLISHER_ID = 0, 1              # rmw_zenoh numbers a context's entities from 0

    def __init__(self, session, name: str, domain_id: int = 0, topic: str | None = None,
                 distro: str = "jazzy", depth: int = 10):
        import zenoh

        self.namespace = "/" + ros_name(name)
        self.topic = fully_qualified(topic or "odom", self.namespace)
        self.frame_id, self.child_frame_id = f"{ros_name(name)}/pipe", f"{ros_name(name)}/base_link"
        type_hash, zid = TYPE_HASHES[distro], str(session.info.zid())
        self.keyexpr = topic_keyexpr(domain_id, self.topic, type_hash)
        self.node_token = node_token(domain_id, zid, self.NODE_ID, self.namespace)
        self.publisher_token = publisher_token(domain_id, zid, self.NODE_ID, self.PUBLISHER_ID, self.namespace,
                                               self.topic, type_hash, qos_keyexpr(depth))
        self.gid = gid(self.publisher_token)
        self.sequence_number = 0
        self._decls = []
        try:
            self._publisher = session.declare_publisher(self.keyexpr, reliability=zenoh.Reliability.RELIABLE,
                                                        congestion_control=zenoh.CongestionControl.DROP)
            self._decls.append(self._publisher)
            for token in (self.node_token, self.publisher_token):
                self._decls.append(session.liveliness().declare_token(token))
        except Exception:
            self.close()
            raise

    def publish(self, stamp_ns: int, distance_m: float, speed_m_s: float | None, sigma_m: float | None,
                sigma_speed: float | None) -> bytes:
        """One Odometry stamped `stamp_ns` (sensor time, ns); returns the CDR payload it sent."""
        payload = odometry_cdr(stamp_ns, distance_m, speed_m_s, sigma_m, sigma_speed, self.frame_id,
                               self.child_frame_id)
        self.sequence_number += 1
        self._publisher.put(payload, attachment=attachment(self.sequence_number, time.time_ns(), self.gid))
        return payload

    def close(self):
        for d in reversed(self._decls):
            try:
                d.undeclare()
            except Exception:               # already gone with the session
                pass
        self._decls = []


class Ros2Output(Output):
    """The daemon's ROS 2 topic: an Odometry per published estimate, on the link's own session (made
    when the session opens, so a network that comes late still gets the topic)."""

    def __init__(self, link, name: str, domain_id: int = 0, topic: str | None = None, distro: str = "jazzy",
                 publish_hz: float = 30.0, clock=time.monotonic):
        self.args = (name, domain_id, topic or None, distro)
        self.every_s, self.clock = 1.0 / publish_hz, clock
        self.node: Ros2Odometry | None = None
        self._last = -float("inf")
        self._epoch_ns = None             # wall clock of sensor time 0: ROS tools want epoch stamps
        link.on_session(self._open)

    def _open(self, session):
        self.node = Ros2Odometry(session, *self.args)

    def write(self, frame, estimate, run):
        now = self.clock()
        if self._epoch_ns is None:
            self._epoch_ns = time.time_ns() - int(estimate.t_s * 1e9)
        if self.node is None or now - self._last < self.every_s:
            return
        self._last = now
        sigma = getattr(estimate, "sigma_m", None)
        self.node.publish(self._epoch_ns + int(estimate.t_s * 1e9), estimate.distance_m, estimate.speed_m_s,
                          sigma, None)

    def close(self):
        if self.node is not None:
            self.node.close()
