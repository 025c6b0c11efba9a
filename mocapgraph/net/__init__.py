"""Network front doors for the servers nodes run (token, Origin and Host checks)."""
