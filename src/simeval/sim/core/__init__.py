"""The scene: the PyBullet world and table (world), poses and zone tests (geometry), the palette (colors), the object
registry and its builders (objects; articulated: jointed bodies and their URDFs; fixtures: drawers, bins, buttons,
walls), and URDF files written on the fly (urdf_files). Nothing here knows about robots, tasks or experts."""
