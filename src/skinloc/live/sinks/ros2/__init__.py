"""The ROS 2 sinks: live over DDS or rclpy (``sink``, with its publisher process) and bags."""
