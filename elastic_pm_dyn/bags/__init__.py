"""rosbag2 bags (mcap or sqlite3) without rclpy: the one way this package reads and writes them.

- :mod:`.msgtypes`: every message type name the package uses, ``NS`` (nanoseconds per
  second) and the text of our own ``BranchForces`` message;
- :mod:`.typestore`: rosbags' ROS 2 Jazzy types with ours registered;
- :mod:`.errors`: :class:`~.errors.BagError`, one line naming the bag, for whatever a
  missing, foreign, truncated or corrupt bag makes rosbags or a storage raise;
- :mod:`.reader`: open a bag (directory or single ``.mcap``/``.db3`` file, with or without
  stored message definitions), its topics, its messages raw or decoded;
- :mod:`.cdr` and :mod:`.decode`: straight from CDR bytes to numpy arrays for the types
  read or written in bulk (several times faster than rosbags), rosbags as the fallback;
- :mod:`.series`: every numeric topic of a small bag as arrays;
- :mod:`.writer`: write a bag (raw CDR, message objects, or rows of a batch at once), readable
  up to its last flush if the writing process is killed;
- :mod:`.metadata`: ``metadata.yaml`` from the moment a bag opens, marked unfinished until it closes;
- :mod:`.mcap_scan`: the complete chunks of an mcap without footer (a killed writer's);
- :mod:`.repair`: a finished copy of a cut or damaged bag (``elastic-pm-dyn bag-repair``).

The modules import one another by their own names (this ``__init__`` re-exports nothing),
so that the light ones (message type names) never pull in rosbags.
"""
