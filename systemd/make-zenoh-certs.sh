#!/usr/bin/env bash
# Certificates for crawlerd's secure Zenoh configuration (docs/deploy.md, "Securing the network"):
# a CA of your own, the crawler's server certificate, and one client certificate per operator
# laptop (CN=operator: the name the access-control policy trusts with commands).
#   systemd/make-zenoh-certs.sh DIR [CRAWLER_HOST_OR_IP ...]     (default: localhost 127.0.0.1)
# Writes DIR/ca.pem, ca.key (keep it off the crawler), crawler.pem/.key, operator.pem/.key.
set -euo pipefail
dir=${1:?usage: $0 DIR [CRAWLER_HOST_OR_IP ...]}; shift
hosts=("${@:-localhost 127.0.0.1}"); [ $# -eq 0 ] && hosts=(localhost 127.0.0.1)
command -v openssl >/dev/null || { echo "make-zenoh-certs: openssl is missing (sudo apt install openssl)" >&2; exit 2; }
mkdir -p "$dir" && cd "$dir"
san=""
for h in "${hosts[@]}"; do
  if [[ $h =~ ^[0-9.]+$ || $h == *:* ]]; then san+="IP:$h,"; else san+="DNS:$h,"; fi
done
openssl req -x509 -newkey rsa:2048 -nodes -days 3650 -keyout ca.key -out ca.pem -subj "/CN=crawlerd CA" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
leaf() {   # name common-name extensions
  openssl req -newkey rsa:2048 -nodes -keyout "$1.key" -out "$1.csr" -subj "/CN=$2" 2>/dev/null
  printf '%s\n' "$3" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA ca.pem -CAkey ca.key -CAcreateserial -days 825 -out "$1.pem" \
    -extfile "$1.ext" 2>/dev/null
  rm -f "$1.csr" "$1.ext"
}
leaf crawler "${hosts[0]}" "subjectAltName=${san%,}
extendedKeyUsage=serverAuth,clientAuth
basicConstraints=CA:FALSE"
leaf operator operator "subjectAltName=DNS:operator
extendedKeyUsage=clientAuth,serverAuth
basicConstraints=CA:FALSE"
chmod 600 ./*.key
echo "certificates in $dir: ca.pem (ca.key stays with you), crawler.pem/.key, operator.pem/.key"
