"""The rig and the controller as separate nodes over Eclipse Zenoh (docs/nodes.md).

:mod:`.messages` (the wire messages: ROS 2 types as CDR), :mod:`.transport` (the Zenoh session,
keys, sequence numbers), :mod:`.rig` (the rig node: the closed loop in real time with a remote
controller, the watchdog) and :mod:`.controller` (the controller node). The submodules load Zenoh
and the message codecs; this package itself holds only the defaults the command line shows.
"""

__all__ = ["DEFAULT_ENDPOINT", "DEFAULT_PREFIX"]

#: Where the rig listens and a controller node connects by default (loopback, no router).
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: The default key prefix of one rig's topics.
DEFAULT_PREFIX = "capsule_mpc/rig0"
