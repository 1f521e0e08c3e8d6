"""The library's data on disk, each read back without unpickling: skill libraries (rollouts), label sets, and the
export zip of a tuned behaviour."""
