"""The recording format and its files.

Every MCAP schema and encoder the appliance writes (``schemas``; the JSON message schemas and
their checks in ``jsonschemas``; the schema record type in ``message``), the recorder thread
(``recorder``), the reader (``reader``), crash recovery (``recovery``) and the file metadata
(``metadata``). Camera frames are encoded by ``drivers.camera.mcap_format`` (the MCAP replay
camera decodes them there and ``drivers`` must not import ``appliance``);
``schemas.frame_records`` hands them to the recorder.
"""
