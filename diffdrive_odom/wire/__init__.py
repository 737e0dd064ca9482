"""ROS 2 message bytes and fields: CDR codecs, and message fields to the core's numbers.

Pure as the core is: standard library and numpy only, no rclpy, message or bag
library, so the node, bag I/O and the sinks share one codec that the import
contracts keep free of ROS.
"""

__all__ = ['cdr', 'conversions', 'imu', 'jointstate', 'odometry']
