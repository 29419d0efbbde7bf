"""Reprocessing recordings: the core of ``ogiflow replay`` and ``ogiflow reprocess``.

``source`` reads what a recording needs to be processed again (geometry, parameters, wind,
its stereo pairs); ``segments`` cuts it into time segments and runs the chain over them;
``sink`` writes results synchronously to MCAP; ``jobs``, ``manifest``, ``tasks`` and
``runner`` spread segments over Ray tasks, resumably. Only ``runner`` imports Ray.
"""
