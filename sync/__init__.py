"""sync package: the synchronisation of section V and the ΔT measurement of section VI.

Shape letters mean one thing in every module here: N joint samples (t_k^R, q_k), M sensor
measurements (triggers, queries t_i^S, seam points), J joints per sample.
"""
