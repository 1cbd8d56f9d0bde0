"""File formats: TUM trajectories, g2o pose graphs, peers' map formats, observations as JSON
lines (``map.json`` is :class:`markergraph.markermap.MarkerMap`'s own)."""

from typing import TYPE_CHECKING

from markergraph.common.lazy import lazy_package

if TYPE_CHECKING:
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

lazy_package(
    __name__,
    {
        "markergraph.formats.g2o": (
            "MARKER_VERTEX_OFFSET",
            "write_g2o",
            "write_g2o_3d",
        ),
        "markergraph.formats.observations": (
            "read_observations",
            "write_observations",
        ),
        "markergraph.formats.peers": (
            "ExportFormat",
            "export_map",
        ),
        "markergraph.formats.tum": (
            "read_tum",
            "write_tum",
            "write_tum_3d",
        ),
    },
)
