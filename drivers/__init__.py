"""Device drivers: cameras and anemometers behind small interfaces, each with real,
simulated and replay back ends."""
