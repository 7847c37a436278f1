#!/usr/bin/env bash
# Install viscover into /opt/viscover on a ground station or a companion computer.
# Usage (from a checkout): sudo deploy/install.sh
#
# Program files go to /opt/viscover (replaced by every install); the user's configuration lives
# in /etc/viscover and is never overwritten: viscover.env, the Zenoh configs (*.json5) and the
# team's certificates (certs/, from deploy/make-certs.py) are only created when missing.
# The units run as the dedicated system user viscover (no login shell, no home).
set -euo pipefail
src="$(cd "$(dirname "$0")/.." && pwd)"
dest=/opt/viscover
etc=/etc/viscover
id -u viscover >/dev/null 2>&1 || \
  useradd --system --user-group --no-create-home --home-dir /var/lib/viscover \
          --shell /usr/sbin/nologin viscover
mkdir -p "$dest"
cp -r "$src/agent" "$src/groundstation" "$src/broker_config" "$src/scenarios" \
      "$src/pyproject.toml" "$src/README.md" "$dest/"
python3 -m venv "$dest/.venv"
"$dest/.venv/bin/pip" install --quiet "$dest"
# Configuration: root owns it, the viscover group reads it, nobody else.
install -d -m 0750 -o root -g viscover "$etc" "$etc/certs"
[ -f "$etc/viscover.env" ] || install -m 0640 -o root -g viscover \
  "$src/deploy/viscover.env.example" "$etc/viscover.env"
for f in "$src"/broker_config/*.json5; do
  [ -f "$etc/$(basename "$f")" ] || install -m 0640 -o root -g viscover "$f" "$etc/"
done
# Keys copied into certs/ by hand must stay readable by viscover only (see README).
find "$etc/certs" -type f \( -name '*.key' -o -name '*.sign' \) \
  -exec chown root:viscover {} + -exec chmod 0640 {} +
cp "$src"/deploy/systemd/*.service /etc/systemd/system/
systemctl daemon-reload
echo "Installed in $dest; configuration in $etc (kept across reinstalls)."
echo "Edit $etc/viscover.env (and, for the secured profile, copy this machine's files from"
echo "deploy/make-certs.py's team directory into $etc/certs), then enable the units you need:"
echo "  ground station: systemctl enable --now viscover-router viscover-groundstation"
echo "  each drone:     systemctl enable --now viscover-agent@<ID>"
