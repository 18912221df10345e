"""The built-in worlds by name, and loading a world from a name or a map_server map."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from bioslam.sim.hall import hall_world
from bioslam.sim.mapworld import world_from_map
from bioslam.sim.maze import maze_world
from bioslam.sim.rooms import rooms_world
from bioslam.sim.warehouse import warehouse_world
from bioslam.sim.world import World

#: Name -> builder of each built-in world: the paper's maze, and layouts that repeat.
WORLDS: dict[str, Callable[[], World]] = {
    "maze": maze_world,
    "warehouse": warehouse_world,
    "rooms": rooms_world,
    "hall": hall_world,
}


def load_world(spec: str | Path) -> World:
    """A built-in world by name (:data:`WORLDS`) or a map_server map YAML by path."""
    name = str(spec)
    if name in WORLDS:
        return WORLDS[name]()
    path = Path(spec)
    if path.suffix.lower() not in (".yaml", ".yml"):
        raise ValueError(
            f"world must be one of {', '.join(WORLDS)} or a map YAML file, got {name!r}"
        )
    return world_from_map(path)
