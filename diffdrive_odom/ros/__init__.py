"""The rclpy layer (QoS, parameter glue, executors, diagnostics) and the thin nodes.

May import: ``diffdrive_odom.core``, ``diffdrive_odom.settings``, ``diffdrive_odom.wire``,
rclpy and messages;
never the tools or the demo.
"""
