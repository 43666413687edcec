#!/usr/bin/env bash
# The offline 2D keypoint detector's own virtual environment (crates/panoman-py/python/panoman/detect.py):
# ${PANOMAN_DETECT_VENV:-target/detect}, made with `${PANOMAN_DETECT_PYTHON:-python3} -m venv`
# (CPython 3.9 to 3.12: mediapipe 0.10.14 has no wheel for later ones).
#
# Separate from the project's environment (scripts/python-setup.sh, target/python): mediapipe
# 0.10.14 predates numpy 2 (numpy 1.26.4 here; the project pins numpy 2) and needs
# opencv-contrib-python and protobuf < 5.
# mediapipe 0.10.14 is the pinned detector: its Holistic solution carries its models inside
# the wheel, so the detector runs offline (later releases download models at run time).
#
# Every package is pinned, dependencies included, and installed with --no-deps: what is below
# is the whole environment, as verified. mediapipe's declared dependencies jax, jaxlib and
# sounddevice are left out: the Holistic solution never imports them (only the GenAI converter
# and the audio tasks do), and they are large. `pip check` therefore lists them as
# missing; that is expected. matplotlib stays: `import mediapipe` imports it.
#
# Idempotent: a second run only reinstalls when the list below changed.
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${PANOMAN_DETECT_VENV:-target/detect}"
python="${PANOMAN_DETECT_PYTHON:-python3}"
requirements="$(cat <<'EOF'
# scripts/detect-setup.sh: the detector's environment (installed with --no-deps)
mediapipe==0.10.14
numpy==1.26.4
opencv-contrib-python==4.10.0.84
protobuf==4.25.9
absl-py==2.5.1
attrs==26.1.0
flatbuffers==25.12.19
matplotlib==3.11.2
contourpy==1.3.3
cycler==0.12.1
fonttools==4.69.1
kiwisolver==1.5.1
packaging==26.4
pillow==13.0.0
pyparsing==3.3.3
python-dateutil==4.0.0
tzdata==2026.6
tqdm==4.70.1
EOF
)"
if [ ! -x "$venv/bin/python" ]; then
    if ! "$python" -c 'import sys; sys.exit(not ((3, 9) <= sys.version_info[:2] <= (3, 12)))'; then
        echo "detect-setup: $python is Python $("$python" -c 'import sys; print(sys.version.split()[0])'):" \
            "mediapipe 0.10.14 needs CPython 3.9 to 3.12 (set PANOMAN_DETECT_PYTHON)" >&2
        exit 2
    fi
    "$python" -m venv "$venv"
fi
if ! printf '%s\n' "$requirements" | cmp -s - "$venv/.requirements"; then
    printf '%s\n' "$requirements" > "$venv/.requirements.new"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps \
        -r "$venv/.requirements.new"
    mv "$venv/.requirements.new" "$venv/.requirements"
fi
"$venv/bin/python" -c 'import sys, cv2, mediapipe, numpy
print(f"detect-setup: {sys.prefix}: mediapipe {mediapipe.__version__},"
      f" numpy {numpy.__version__}, opencv {cv2.__version__}")'
