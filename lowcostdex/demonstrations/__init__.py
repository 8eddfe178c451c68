"""Demonstrations in one place: the HDF5 demo file (``file``), recording episodes and reading them
as training pairs (``dataset``), kinesthetic recording on a robot or the emulator's virtual hand
(``kinesthetic``), the virtual teachers (``teachers``) and the ``record-demos`` command (``cli``).
"""
