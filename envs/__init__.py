"""The UR5 Reacher Gymnasium environment (see ../shared/DESIGN.md)."""
