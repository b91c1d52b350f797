"""The lab: experiments, benches, evaluation against the truth and campaign reporting, apart from the
bench's hardware and world models (docs/experiments.md)."""
