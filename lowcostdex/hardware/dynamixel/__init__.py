"""Dynamixel servos: Protocol 2.0 on the wire, control tables as data, the driver, port discovery and motor set-up."""
