"""How good a trajectory is: KITTI metrics and d² (`metrics`), trajectory files (`trajectory`: TUM and
KITTI), a run's report (`report`), its plot (`plot`) and the GNSS/INS reference it is judged
against (`reference`: clock and heading alignment)."""
