"""Drive logs: MCAP and ROS 1/2 bags read into and written from the track table."""
