"""Diagnosis of one throw and of a switch over its throws: fitting every hypothesis (estimation), deciding which
faults are present (isolation, fault sets) and the per-switch state that commissions, tracks and repairs
(switch_diagnoser)."""
