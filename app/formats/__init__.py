"""File formats: TUM trajectories, g2o pose graphs, peers' map formats, observations as JSON
lines (``map.json`` is :class:`markergraph.markermap.MarkerMap`'s own)."""

from markergraph.formats.g2o import MARKER_VERTEX_OFFSET, write_g2o, write_g2o_3d
from markergraph.formats.observations import read_observations, write_observations
from markergraph.formats.peers import ExportFormat, export_map
from markergraph.formats.tum import read_tum, write_tum, write_tum_3d

__all__ = [
    "MARKER_VERTEX_OFFSET",
    "ExportFormat",
    "export_map",
    "read_observations",
    "read_tum",
    "write_g2o",
    "write_g2o_3d",
    "write_observations",
    "write_tum",
    "write_tum_3d",
]
