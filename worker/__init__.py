"""RQ job functions (thin shells over vpp_core) and the settings both shells read."""
