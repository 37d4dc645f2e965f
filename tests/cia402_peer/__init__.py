"""An independent CiA 301/402 drive for tests (see :mod:`cia402_peer.drive`)."""

from cia402_peer.drive import Ds402, Nmt, PeerDrive

__all__ = ["Ds402", "Nmt", "PeerDrive"]
