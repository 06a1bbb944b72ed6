"""mplib planner plugin."""
