# The accuracy gate's simulated flights (sourced by scripts/accuracy_gate.sh and bench/gate_seeds.sh): FLIGHTS, each
# one's plan keys (hal/sim/sim_plan.h) in PLAN[name] on top of COMMON's, its seed first.
# shellcheck shell=bash disable=SC2034
# The flights: name, then plan keys (hal/sim/sim_plan.h) on top of the common ones.
COMMON="frame_width: 400
frame_height: 300
gsd: 0.75
strips: 3
forward_overlap: 0.75
side_overlap: 0.4
noise_sigma: 1.0"
declare -A PLAN
FLIGHTS=(easy jitter_tilt barrel_lens barrel_jitter water_gps)
PLAN[easy]="seed: 3"
PLAN[jitter_tilt]="seed: 7
yaw_jitter_deg: 3.0
altitude_change: 0.12
tilt_deg: 1.5
noise_sigma: 2.5
blur_px: 1.5
jpeg_quality: 90"
PLAN[barrel_lens]="seed: 11
k1: -0.25"
# A -5 % barrel under yaw/altitude jitter and tilts: the lens is estimated twice (lens_calibration.rematch).
PLAN[barrel_jitter]="seed: 17
k1: -0.128
yaw_jitter_deg: 5.0
altitude_change: 0.2
tilt_deg: 2.5
noise_sigma: 3.0
blur_px: 1.5
jpeg_quality: 90"
PLAN[water_gps]="seed: 13
gps: 1
water_from: 0.45
water_to: 0.6"

# The photograph the flights are simulated over (bundled with the project).
FLIGHT_CANVAS="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)/tests/data/caliterra_small/images/IMG_9360.jpg"

# flight_plan NAME [SEED]: flight NAME's plan for uavmosaic-sim, its seed replaced by SEED when given (a key set
# earlier wins over the same key later).
flight_plan() {
  {
    if [[ -n ${2:-} ]]; then echo "seed: $2"; fi
    echo "${PLAN[$1]}"
    echo "$COMMON"
  } | awk -F': ' '!seen[$1]++'
}
