"""DDPG + Hindsight Experience Replay in PyTorch (see ../shared/DESIGN.md)."""
