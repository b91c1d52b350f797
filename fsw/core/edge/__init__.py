"""The cliff edge and what keeps the rover off it (docs/algorithm.md §2): edge extraction, the path along it, the
geofence, known ground and look-before-you-drive."""
