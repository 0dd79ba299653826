#!/usr/bin/env bash
# Makes a test CA and one TLS certificate per host for a launch file's [security] table.
#
# usage: scripts/make-certs.sh OUT_DIR HOST=ADDRESS [HOST=ADDRESS ...]
#   e.g. scripts/make-certs.sh certs a=10.0.0.1 b=10.0.0.2
# writes OUT_DIR/ca.pem (+ ca.key, keep it private), and OUT_DIR/HOST.pem + HOST.key per host:
# ECDSA P-256, signed by the CA, valid for the host's address (an IP or a DNS name, checked by
# the peers that connect to it) and for both ends of a link (mutual TLS). For a lab, not a PKI.
set -euo pipefail
if [ $# -lt 2 ]; then
  sed -n '2,9p' "$0" >&2
  exit 2
fi
out=$1
shift
mkdir -p "$out"
umask 077
days=3650
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days "$days" \
  -subj "/CN=Deep Contact test CA" -keyout "$out/ca.key" -out "$out/ca.pem" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
for spec in "$@"; do
  host=${spec%%=*}
  address=${spec#*=}
  if [ -z "$host" ] || [ "$host" = "$spec" ] || [ -z "$address" ]; then
    echo "make-certs: expected HOST=ADDRESS, got \`$spec\`" >&2
    exit 2
  fi
  if [[ $address =~ ^[0-9.]+$ || $address == *:* ]]; then san="IP:$address"; else san="DNS:$address"; fi
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -subj "/CN=$host" \
    -keyout "$out/$host.key" -out "$out/$host.csr" 2>/dev/null
  ext=$(mktemp)
  printf 'subjectAltName=%s\nbasicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n' "$san" >"$ext"
  openssl x509 -req -in "$out/$host.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
    -days "$days" -out "$out/$host.pem" -extfile "$ext" 2>/dev/null
  rm -f "$ext" "$out/$host.csr"
  echo "$out/$host.pem: $host ($san)"
done
chmod 644 "$out"/*.pem
