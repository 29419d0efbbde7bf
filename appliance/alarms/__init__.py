"""Alarm sinks: leak events, status and summaries for the plant's systems (MQTT)."""
