"""Integrations beside the MPC core: the Gymnasium environment (``integrations.env``) and the
meshcat visualiser (``integrations.viz``)."""
