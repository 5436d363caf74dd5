"""The name of a controller node's ready token: the controller's name and its command publisher.

A controller node ready for a run declares the liveliness token
``<prefix>/alive/controller/<run>/<name>~<id>``, ``<id>`` the 16 hex digits of its command
publisher's id (the ``publisher_id`` of its commands' headers): the rig tells by it which node a
command comes from, and applies only those of the node driving the run.
"""

from __future__ import annotations

__all__ = ["node_name", "node_publisher", "node_token"]


def node_token(name: str, publisher_id: int) -> str:
    """The last chunk of a controller node's ready token: its name and its command publisher's id."""
    return f"{name}~{publisher_id:016x}"


def node_name(token: str) -> str:
    """The controller's name in a ready token (:func:`node_token`)."""
    return token.rsplit("~", 1)[0]


def node_publisher(token: str) -> int | None:
    """The command publisher's id in a ready token (None if it has none)."""
    name, _, hex_id = token.rpartition("~")
    try:
        return int(hex_id, 16) if name else None
    except ValueError:
        return None
