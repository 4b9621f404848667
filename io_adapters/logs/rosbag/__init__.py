"""io_adapters/logs/rosbag."""
