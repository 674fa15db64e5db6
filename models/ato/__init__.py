"""The automatic train operation for one span: re-planner, stopping, supervisor, controller."""
