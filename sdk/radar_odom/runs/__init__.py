"""A recording run as a library: odometry over a whole recording, its outputs written and evaluated.

`run_sequence` (`radar_odom.runs.run_sequence`) is what `radar-odom run` does, as a function; `radar-odom fleet`
runs it per recording on Ray workers and `radar-odom demo` on a simulated drive. It sits below the command line
(``commands/``), so neither ``fleet/`` nor the torch side imports the CLI layer.
"""
