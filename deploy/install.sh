#!/usr/bin/env bash
# Install viscover into /opt/viscover on a ground station or a companion computer.
# Usage (from a checkout): sudo deploy/install.sh
set -euo pipefail
src="$(cd "$(dirname "$0")/.." && pwd)"
dest=/opt/viscover
mkdir -p "$dest" /etc/viscover
cp -r "$src/agent" "$src/groundstation" "$src/broker_config" "$src/scenarios" \
      "$src/pyproject.toml" "$src/README.md" "$dest/"
python3 -m venv "$dest/.venv"
"$dest/.venv/bin/pip" install --quiet "$dest"
[ -f /etc/viscover/viscover.env ] || cp "$src/deploy/viscover.env.example" /etc/viscover/viscover.env
cp "$src"/deploy/systemd/*.service /etc/systemd/system/
systemctl daemon-reload
echo "Installed in $dest. Edit /etc/viscover/viscover.env, then enable the units you need:"
echo "  ground station: systemctl enable --now viscover-router viscover-groundstation"
echo "  each drone:     systemctl enable --now viscover-agent@<ID>"
