"""MAVProxy support shipped with the project: ``module load ground.mavproxy.safer`` (docs/ground.md, "MAVProxy")."""
