"""Shared test helpers."""

from workers.geometry import LaserRays, PlaneGrid


def plane_grid(camera, *, depth, refractive_index=1.34, guard=0.125):
    """The renderer's plane grid for `camera` lit by the default (matching) laser."""
    laser = LaserRays.from_platform(
        position=camera.position,
        rotation=camera.rotation,
        beam="divergent",
        field_of_view=camera.field_of_view,
        rays=camera.pixels,
        reference_range=camera.position[2],
    )
    return PlaneGrid.covering(
        camera=camera,
        lattice=laser.central(),
        depth=depth,
        refractive_index=refractive_index,
        guard=guard,
    )
