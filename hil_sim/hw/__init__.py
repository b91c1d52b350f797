"""Hardware models of the bench: the bytes on the CAN bus, the serial line and the camera link."""
