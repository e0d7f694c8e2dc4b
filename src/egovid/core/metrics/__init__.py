"""Metrics: masked inter-frame transformation fidelity (ITF, OITF, RITF), pose error, BD-rate."""
