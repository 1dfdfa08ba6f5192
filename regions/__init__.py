"""Goal constraint regions of the UR5 Reacher task (see ../shared/DESIGN.md)."""
