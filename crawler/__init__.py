"""crawlerd: visual odometry for in-pipe crawlers."""

__version__ = "0.1.0"
