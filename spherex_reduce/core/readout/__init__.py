"""The readout: when every sample of a frame is taken, and which reads a stored frame holds.

``schedule`` (`~spherex_reduce.ReadoutSchedule`: row chopping, reference and
phantom reads), ``read_order`` (explicit read orders), ``frame_times`` (when
each stored frame was read) and ``groups`` (groups of reads averaged into one
stored frame).
"""
