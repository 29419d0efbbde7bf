"""Pure numerical code of the scene-flow method (Rangel, Schmoll, Kroll, WACV 2020).

Nothing here imports :mod:`appliance` or :mod:`drivers`.
"""
