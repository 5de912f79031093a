"""Pure math: arrays in, arrays out. Nothing here reads files, opens sockets or logs.

Array conventions: positions ``(T, J, 3)`` in metres, observation masks ``(T, J)``
bool (True = observed), bones ``(B, 2)`` int joint-index pairs, rates in Hz.
"""
