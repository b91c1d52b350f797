"""The RECON-bot's fixer: the task that answers the Cliff-bot's fix requests (:mod:`.task`) and
the camera pose of a fix with its covariance (:mod:`.fix_pose`)."""
