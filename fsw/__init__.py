"""MIT-SAFER flight software for the RECON-bot."""

__version__ = "0.1.0"
