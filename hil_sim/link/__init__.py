"""The map link on the bench: the seeded radio channel model (``radio_channel``), the real-time
driver loop of one link end (``link_pump``) and the impairment relay over UDP (``udp_relay``)."""
