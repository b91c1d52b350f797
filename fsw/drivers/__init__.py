"""Device drivers: one device each; timeouts, retries, fault flags; no algorithm."""
