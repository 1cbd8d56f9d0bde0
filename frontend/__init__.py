"""markergraph.frontend: camera frames and MCAP logs to marker observations (OpenCV, mcap)."""

__all__: list[str] = []
