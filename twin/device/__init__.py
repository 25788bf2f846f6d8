"""Devices behind one interface: the rig over serial, its emulation, and the protocol between them."""
