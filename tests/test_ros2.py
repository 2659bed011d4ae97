"""crawler/ros2.py: nav_msgs/msg/Odometry as rmw_zenoh sends it, checked against independent parts:
rosbags (its own CDR implementation and RIHS01 hashes), zenoh's own zenoh-ext serializer for the
attachment, xxhash for the GID, and a second zenoh session on loopback that subscribes like a ROS 2
node on rmw_zenoh would."""

import math
import time

import numpy as np
import pytest
import xxhash
import zenoh
from rosbags.typesys import Stores, get_typestore
from zenoh.ext import Int64, z_deserialize

from conftest import wait_for
from crawler.errors import BadConfig
from crawler.link import make_zenoh_config
from crawler.ros2 import (TYPE_HASHES, UNKNOWN_VARIANCE, Ros2Odometry, attachment, fully_qualified, gid,
                          node_token, odometry_cdr, publisher_token, qos_keyexpr, ros_name, stamp,
                          topic_keyexpr)

ZID = "1d9c4b43061a9aaee02d1fedf279cc39"
JAZZY = get_typestore(Stores.ROS2_JAZZY)
HUMBLE = get_typestore(Stores.ROS2_HUMBLE)


def test_key_expressions_are_rmw_zenohs():
    topic = fully_qualified("odom", "/crawler1")
    assert topic == "/crawler1/odom" and fully_qualified("/robot/pipe_odom", "/crawler1") == "/robot/pipe_odom"
    h = TYPE_HASHES["jazzy"]
    assert topic_keyexpr(0, topic, h) == f"0/crawler1/odom/nav_msgs::msg::dds_::Odometry_/{h}"
    assert topic_keyexpr(7, "/odom", TYPE_HASHES["humble"]) == (
        "7/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported")
    assert node_token(0, ZID, 0, "/crawler1") == f"@ros2_lv/0/{ZID}/0/0/NN/%/%crawler1/crawlerd"
    assert publisher_token(0, ZID, 0, 1, "/crawler1", topic, h, qos_keyexpr(10)) == (
        f"@ros2_lv/0/{ZID}/0/1/MP/%/%crawler1/crawlerd/%crawler1%odom/nav_msgs::msg::dds_::Odometry_/{h}"
        "/::,10:,:,:,,")
    # rclcpp's default publisher QoS (reliable, volatile, keep last 10); 42 is rmw_zenoh's own default depth
    assert (qos_keyexpr(7), qos_keyexpr(42), qos_keyexpr(5, "best_effort")) == ("::,7:,:,:,,", "::,:,:,:,,",
                                                                              "2::,5:,:,:,,")
    assert ros_name("pipe-cam-2") == "pipe_cam_2" and ros_name("2nd") == "c2nd"
    for bad in ("odom/", "2odom", "a//b", "odom-1", ""):
        with pytest.raises(BadConfig, match="not a ROS 2 topic name"):
            fully_qualified(bad, "/crawler1")


def test_the_type_hash_is_rosidls():
    assert TYPE_HASHES["jazzy"] == JAZZY.hash_rihs01("nav_msgs/msg/Odometry")


def test_the_gid_is_the_xxh3_128_of_the_token_low_half_first():
    token = publisher_token(0, ZID, 0, 1, "/crawler1", "/crawler1/odom", TYPE_HASHES["jazzy"], qos_keyexpr())
    h = xxhash.xxh3_128(token.encode()).intdigest()
    low, high = h & (2**64 - 1), h >> 64
    assert gid(token) == low.to_bytes(8, "little") + high.to_bytes(8, "little")
    assert len(token) > 128                  # XXH3's 129..240 byte path, as for a real token


def test_the_attachment_is_what_zenoh_ext_serializes():
    g = bytes(range(16))
    raw = attachment(3, 1_700_000_000_123_456_789, g)
    assert len(raw) == 33 and raw[16] == 16
    assert z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(raw)) == (3, 1_700_000_000_123_456_789, g)
    with pytest.raises(ValueError, match="16 bytes"):
        attachment(1, 0, b"short")


@pytest.mark.parametrize("store", [JAZZY, HUMBLE], ids=["jazzy", "humble"])
def test_the_cdr_payload_decodes_with_rosbags_and_is_byte_identical_to_its_encoder(store):
    raw = odometry_cdr(1_700_000_000_123_456_789, 12.5, 0.2, 0.01, 0.005, "crawler1/pipe", "crawler1/base_link")
    assert raw[:4] == b"\x00\x01\x00\x00"           # CDR little endian encapsulation
    m = store.deserialize_cdr(raw, "nav_msgs/msg/Odometry")
    assert (m.header.stamp.sec, m.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert (m.header.frame_id, m.child_frame_id) == ("crawler1/pipe", "crawler1/base_link")
    p, q = m.pose.pose.position, m.pose.pose.orientation
    assert (p.x, p.y, p.z, q.x, q.y, q.z, q.w) == (12.5, 0, 0, 0, 0, 0, 1)
    assert (m.twist.twist.linear.x, m.twist.twist.angular.z) == (0.2, 0.0)
    pose_cov, twist_cov = m.pose.covariance.reshape(6, 6), m.twist.covariance.reshape(6, 6)
    assert pose_cov[0, 0] == pytest.approx(1e-4) and twist_cov[0, 0] == pytest.approx(2.5e-5)
    assert np.all(np.diag(pose_cov)[1:] == UNKNOWN_VARIANCE) and np.count_nonzero(pose_cov - np.diag(np.diag(pose_cov))) == 0
    assert store.serialize_cdr(m, "nav_msgs/msg/Odometry") == raw

    held = store.deserialize_cdr(odometry_cdr(-1, 3.0, None, None, 0.1, "a", "b"), "nav_msgs/msg/Odometry")
    assert (held.header.stamp.sec, held.header.stamp.nanosec) == (-1, 999_999_999)
    assert held.twist.twist.linear.x == 0.0 and held.twist.covariance[0] == UNKNOWN_VARIANCE   # speed unknown
    assert held.pose.covariance[0] == UNKNOWN_VARIANCE
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="only finite numbers"):
            odometry_cdr(0, bad, 0.1, 0.01, 0.01, "a", "b")
    with pytest.raises(ValueError, match="does not fit"):
        stamp(2**31 * 10**9)


def test_a_ros2_subscriber_on_loopback_sees_the_topic_the_tokens_and_the_messages(zenoh_pair):
    daemon = zenoh.open(make_zenoh_config("peer", listen=zenoh_pair["listen"], multicast=False))
    ros = zenoh.open(make_zenoh_config("peer", connect=zenoh_pair["connect"], multicast=False))
    samples, tokens = [], []
    try:
        key = f"0/crawler1/odom/nav_msgs::msg::dds_::Odometry_/{TYPE_HASHES['jazzy']}"
        _sub = ros.declare_subscriber(key, lambda s: samples.append((s.payload.to_bytes(), s.attachment.to_bytes())))
        _graph = ros.liveliness().declare_subscriber("@ros2_lv/0/**", lambda s: tokens.append((str(s.key_expr),
                                                                                            s.kind)), history=True)
        odom = Ros2Odometry(daemon, "crawler1")
        assert odom.keyexpr == key and odom.topic == "/crawler1/odom"
        assert wait_for(lambda: len(tokens) >= 2, timeout=10)
        assert wait_for(lambda: odom._publisher.matching_status.matching, timeout=10)   # the route is there
        sent = []
        for i in range(3):
            sent.append(odom.publish(1_000_000_000 * (10 + i), 0.5 * i, 0.25, 0.001 * (i + 1), 0.01))
        assert wait_for(lambda: len(samples) == 3, timeout=10)

        zid = str(daemon.info.zid())
        names = {t for t, kind in tokens if kind == zenoh.SampleKind.PUT}
        assert names == {odom.node_token, odom.publisher_token}
        assert odom.node_token == f"@ros2_lv/0/{zid}/0/0/NN/%/%crawler1/crawlerd"
        assert odom.publisher_token.startswith(f"@ros2_lv/0/{zid}/0/1/MP/%/%crawler1/crawlerd/%crawler1%odom/")
        before = time.time_ns()
        for i, (payload, att) in enumerate(samples):
            assert payload == sent[i]
            m = JAZZY.deserialize_cdr(payload, "nav_msgs/msg/Odometry")
            assert m.header.stamp.sec == 10 + i and m.pose.pose.position.x == 0.5 * i
            assert m.twist.twist.linear.x == 0.25 and m.pose.covariance[0] == pytest.approx((0.001 * (i + 1)) ** 2)
            assert m.header.frame_id == "crawler1/pipe" and m.child_frame_id == "crawler1/base_link"
            seq, t_ns, g = z_deserialize(tuple[Int64, Int64, bytes], zenoh.ZBytes(att))
            assert seq == i + 1 and abs(t_ns - before) < 30e9
            assert g == gid(odom.publisher_token)          # as a ROS 2 graph cache derives it from the token
        odom.close()
        assert wait_for(lambda: sum(1 for _, k in tokens if k == zenoh.SampleKind.DELETE) == 2, timeout=10)
    finally:
        ros.close()
        daemon.close()


def test_bad_ros2_settings_are_named(zenoh_pair):
    session = zenoh.open(make_zenoh_config("peer", listen=zenoh_pair["listen"], multicast=False))
    try:
        from crawler import settings

        with pytest.raises(BadConfig, match=r"\[ros2\] domain_id = 300 must be between 0 and 232"):
            settings.load(None, ["ros2.domain_id=300"])
        with pytest.raises(BadConfig, match=r"\[ros2\] distro = 'iron' must be one of jazzy, humble"):
            settings.load(None, ["ros2.distro='iron'"])
        with pytest.raises(BadConfig, match="topic = 'odom/'"):
            settings.load(None, ["ros2.topic='odom/'"])
        with pytest.raises(BadConfig, match="topic = 'odom/'"):
            Ros2Odometry(session, "c1", topic="odom/")
        humble = Ros2Odometry(session, "pipe-cam", distro="humble", topic="/inspection/odom")
        assert humble.keyexpr == "0/inspection/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"
        assert "/%pipe_cam/crawlerd/%inspection%odom/" in humble.publisher_token
        humble.close()
    finally:
        session.close()
