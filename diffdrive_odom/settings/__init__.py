"""ROS parameters: the machinery (rcl's params-file rules), one module per node, one registry.

May import: ``diffdrive_odom.core``; never rclpy, the wire codecs, the nodes or the tools.
"""
