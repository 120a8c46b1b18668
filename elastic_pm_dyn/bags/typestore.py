"""The rosbags typestore: ROS 2 Jazzy's message types with this project's registered."""

from __future__ import annotations

from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from elastic_pm_dyn.bags.errors import BagError, one_line
from elastic_pm_dyn.bags.msgtypes import MSG_TEXTS


def make_typestore() -> Typestore:
    """A fresh typestore for ROS 2 Jazzy with this project's messages registered.

    A fresh store each call rather than one shared: rosbags typestores are mutable and
    their users register into them (the recorder adds the installed definitions of the
    types it meets, a reader completes a bag's own), so a shared store would let one
    caller's types leak into another's.
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    for msgtype, text in MSG_TEXTS.items():
        store.register(get_types_from_msg(text, msgtype))
    return store


def register_msg_text(store: Typestore, msgtype: str, text: str) -> None:
    """Add the type ``msgtype`` given by its ``.msg`` text (:class:`BagError` if it is not one)."""
    try:
        store.register(get_types_from_msg(text, msgtype))
    except TypesysError as err:
        raise BagError(f"cannot use the definition of {msgtype}: {one_line(err)}") from None
