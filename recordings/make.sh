#!/usr/bin/env bash
# Regenerate the example recordings: nominal and the paper's four fault scenarios,
# two throws each (left to right, then right to left), noise-free.
set -euo pipefail
cd "$(dirname "$0")"
railswitch simulate --out nominal.mcap
railswitch simulate --out left_bolt.mcap --fault left_bolt_offset=0.05
railswitch simulate --out right_bolt.mcap --fault right_bolt_offset=0.20
railswitch simulate --out missing_bearing.mcap --fault bearing_friction=5000
railswitch simulate --out obstacle.mcap --fault obstacle_friction=1e5 --fault obstacle_position=1.1
