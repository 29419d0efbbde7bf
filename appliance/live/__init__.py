"""The Rerun live view: viewer thread, viewer server process, blueprint and colour maps."""
