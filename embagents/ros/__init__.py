"""The ROS 2 bridge: declarations here, ROS packages only in ``convert``, ``generic`` and ``node``.

This package imports without rclpy: ``system.py`` declares ROS topics with
:class:`RosInput` / :class:`RosOutput` on any machine. Only the bridge actor
imports :mod:`embagents.ros.node` (and with it rclpy).

Example::

    >>> from embagents.ros import QoS, RosInput, RosOutput
    >>> inputs = [RosInput("/text_in", "std_msgs/String")]
    >>> outputs = [RosOutput("cmd_vel", ros_type="geometry_msgs/Twist", qos=QoS(depth=1))]
    >>> inputs[0].topic, outputs[0].ros_topic
    ('text_in', '/cmd_vel')
"""

from embagents.ros.spec import (
    DEFAULT_ROS_TYPE,
    OUTGOING,
    ROS_EXTRA_HINT,
    SUPPORTED,
    QoS,
    RosAction,
    RosCall,
    RosInput,
    RosLifecycle,
    RosOutput,
    RosService,
    check_bridge,
    normalize_ros_type,
    ros_available,
    ros_call,
    ros_type_for,
)

__all__ = [
    "DEFAULT_ROS_TYPE",
    "OUTGOING",
    "QoS",
    "RosAction",
    "ROS_EXTRA_HINT",
    "RosCall",
    "RosInput",
    "RosLifecycle",
    "RosOutput",
    "RosService",
    "SUPPORTED",
    "check_bridge",
    "normalize_ros_type",
    "ros_available",
    "ros_call",
    "ros_type_for",
]
