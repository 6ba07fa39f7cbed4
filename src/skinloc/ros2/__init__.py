"""ROS 2 messages without a ROS install: types, topic names and CDR encoders."""
