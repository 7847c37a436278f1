#!/usr/bin/env bash
# Install viscover into /opt/viscover on a drone's companion computer or on the ground station.
# Usage (from a checkout):
#   sudo deploy/install.sh --drone    # companion computer: the core only (agent, fly, preflight,
#                                     # status, land/stop), no ground-station, report or viewer
#                                     # parts; installs on aarch64 (Raspberry Pi, Jetson)
#   sudo deploy/install.sh --ground   # ground station: viscover[ground,mocap,occlusion-fast]
# Options:
#   --extras LIST   the extras to install instead of the mode's (comma-separated, e.g.
#                   --ground --extras ground,mocap on a machine without an embreex wheel)
#   --root DIR      stage everything under DIR (DIR/opt/viscover, DIR/etc/viscover,
#                   DIR/etc/systemd/system): no user, no owners, no systemctl
#   --skip-venv     do not build the venv (with --root: check the files only)
#
# Program files go to /opt/viscover (replaced by every install); the user's configuration lives
# in /etc/viscover and is never overwritten: viscover.env, the Zenoh configs (*.json5) and the
# team's certificates (certs/, from deploy/make-certs.py) are only created when missing.
# viscover.env as installed names only files made here (the open lab profile); the secured
# profile's files come from deploy/make-certs.py (README: Securing the mesh).
# The units run as the dedicated system user viscover (no login shell, no home).
set -euo pipefail
src="$(cd "$(dirname "$0")/.." && pwd)"
mode="" extras="" extras_set=0 root="" skip_venv=0
die() { echo "install.sh: $*" >&2; exit 2; }
while [ $# -gt 0 ]; do
  case "$1" in
    --drone) mode=drone ;;
    --ground) mode=ground ;;
    --extras) [ $# -ge 2 ] || die "--extras needs a list, e.g. ground,mocap"
              extras="$2" extras_set=1; shift ;;
    --root) [ $# -ge 2 ] || die "--root needs a directory"; root="$(realpath -m "$2")"; shift ;;
    --skip-venv) skip_venv=1 ;;
    -h|--help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) die "unknown option $1 (see --help)" ;;
  esac
  shift
done
[ -n "$mode" ] || die "say what this machine is: --drone (companion computer: core only) or" \
  "--ground (ground station: viscover[ground,mocap,occlusion-fast])"
if [ "$extras_set" = 0 ]; then
  case "$mode" in drone) extras="" ;; ground) extras="ground,mocap,occlusion-fast" ;; esac
fi
for x in ${extras//,/ }; do
  case "$x" in ground|mocap|occlusion-fast) ;; *) die "--extras: unknown extra $x (ground," \
    "mocap, occlusion-fast)" ;; esac
done
dest="$root/opt/viscover"
etc="$root/etc/viscover"
units="$root/etc/systemd/system"
system=1
[ -z "$root" ] || system=0
owner=()  # root:viscover on a real install; the caller's own when staging under --root
if [ "$system" = 1 ]; then
  owner=(-o root -g viscover)
  id -u viscover >/dev/null 2>&1 || \
    useradd --system --user-group --no-create-home --home-dir /var/lib/viscover \
            --shell /usr/sbin/nologin viscover
fi
mkdir -p "$dest" "$units"
cp -r "$src/agent" "$src/groundstation" "$src/broker_config" "$src/scenarios" \
      "$src/pyproject.toml" "$src/README.md" "$dest/"
if [ "$skip_venv" = 0 ]; then
  target="$dest${extras:+[$extras]}"
  log="$(mktemp /tmp/viscover-install-XXXXXX.log)"
  python3 -m venv "$dest/.venv"
  # Binary-only for the two packages without an sdist that builds unattended: a missing wheel
  # is then one clear line below, not a compiler's traceback.
  if ! "$dest/.venv/bin/pip" install --only-binary=embreex,motioncapture "$target" \
       >"$log" 2>&1; then
    missing="$(sed -n 's/.*No matching distribution found for \([A-Za-z0-9_.-]*\).*/\1/p' \
               "$log" | head -n 1)"
    case "$missing" in
      embreex) extra=occlusion-fast ;;
      motioncapture) extra=mocap ;;
      *) extra="" ;;
    esac
    if [ -n "$extra" ]; then
      echo "install.sh: viscover[$extra] cannot be installed on this $(uname -m) machine:" \
        "no wheel of $missing for it; leave it out (--extras LIST without $extra;" \
        "--drone installs no extra) (pip's output: $log)" >&2
    else
      echo "install.sh: pip install $target failed: $(grep -m1 '^ERROR' "$log" || \
        tail -n 1 "$log") (pip's output: $log)" >&2
    fi
    exit 1
  fi
  rm -f "$log"
fi
# Configuration: root owns it, the viscover group reads it, nobody else.
install -d -m 0750 "${owner[@]}" "$etc" "$etc/certs"
[ -f "$etc/viscover.env" ] || install -m 0640 "${owner[@]}" \
  "$src/deploy/viscover.env.example" "$etc/viscover.env"
for f in "$src"/broker_config/*.json5; do
  [ -f "$etc/$(basename "$f")" ] || install -m 0640 "${owner[@]}" "$f" "$etc/"
done
if [ "$system" = 1 ]; then
  # Keys copied into certs/ by hand must stay readable by viscover only (see README).
  find "$etc/certs" -type f \( -name '*.key' -o -name '*.sign' \) \
    -exec chown root:viscover {} + -exec chmod 0640 {} +
fi
if [ "$mode" = drone ]; then
  cp "$src/deploy/systemd/viscover-agent@.service" "$units/"
else
  cp "$src/deploy/systemd/viscover-router.service" \
     "$src/deploy/systemd/viscover-groundstation.service" "$units/"
fi
[ "$system" = 0 ] || systemctl daemon-reload
echo "Installed ($mode${extras:+, extras $extras}) in $dest; configuration in $etc (kept across" \
  "reinstalls)."
echo "Edit $etc/viscover.env (and, for the secured profile, copy this machine's files from"
echo "deploy/make-certs.py's team directory into $etc/certs), then enable the units:"
if [ "$mode" = drone ]; then
  echo "  systemctl enable --now viscover-agent@<ID>"
else
  if ! grep -Eq '^VISCOVER_GS_SOURCE=(sim|motioncapture)[[:space:]]*$' "$etc/viscover.env"; then
    echo "  first set VISCOVER_GS_SOURCE in $etc/viscover.env (motioncapture for real drones," \
      "sim for a rehearsal): viscover-groundstation refuses to start without it"
  fi
  echo "  systemctl enable --now viscover-router viscover-groundstation"
fi
