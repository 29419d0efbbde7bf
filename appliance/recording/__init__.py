"""The recording format and its files.

Every MCAP schema and encoder the appliance writes (``schemas``), the recorder thread
(``recorder``), the reader (``reader``) and crash recovery (``recovery``). The camera frame
messages are encoded by ``drivers.camera.mcap_format`` because the MCAP replay camera reads
them and ``drivers`` must not import ``appliance``.
"""
