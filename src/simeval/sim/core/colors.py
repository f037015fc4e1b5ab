"""The named colours every suite draws from (a module of its own so that simeval.sim.core.objects and
simeval.sim.core.articulated can both import it at the top without importing each other)."""

# Ravens/CLIPort/GenSim's palette (utils.COLORS: muted Tableau 10 colours, 0-255 below), plus GenSim's white and
# our black. Black is lifted off pure black so that it stays visible on the dark workspace tile (0.2 grey):
# zones and lines also get a light outline (simeval.sim.core.objects.OUTLINE). Every pair of colours is at least 50
# apart in 0-255 RGB (tests/test_sim_look.py).
_RAVENS_255 = {
    "blue": (78, 121, 167), "red": (255, 87, 89), "green": (89, 169, 79), "orange": (242, 142, 43),
    "yellow": (237, 201, 72), "purple": (176, 122, 161), "pink": (255, 157, 167), "cyan": (118, 183, 178),
    "brown": (156, 117, 95), "gray": (186, 176, 172), "white": (255, 255, 255), "black": (20, 20, 20),
}
COLORS = {name: tuple(round(v / 255.0, 4) for v in rgb) for name, rgb in _RAVENS_255.items()}
