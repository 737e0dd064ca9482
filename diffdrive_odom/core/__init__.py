"""The pure core: geometry, the CIR step, encoders, estimator, covariance, pipelines, more.

Also limits, path following, the sim model, metrics and calibration. May import the
standard library, numpy and (lazily) scipy, and nothing of this package outside
``diffdrive_odom.core``: never rclpy, message packages or bag libraries.
"""
