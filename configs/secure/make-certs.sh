#!/usr/bin/env bash
# Create a private CA and the TLS certificates for hild's secure Zenoh example (configs/secure/).
#
#   configs/secure/make-certs.sh OUT_DIR SERVER_NAME [SERVER_NAME ...]
#   configs/secure/make-certs.sh /etc/hild/secure robot-arm6.local 192.168.10.2
#
# SERVER_NAME: every DNS name or IP address clients use to reach the daemon (they verify it against the daemon's
# certificate; `tls/192.168.10.2:7447` needs 192.168.10.2 here). Writes into OUT_DIR:
#   ca.pem                          the CA every station trusts (root_ca_certificate)
#   ca.key                          the CA's private key: move it OFF the robot once the certificates exist
#   server.pem, server.key          the daemon's certificate (listen_certificate, listen_private_key)
#   operator|observer|estop.pem/.key  one client certificate per role, CN = the role (connect_certificate, ...)
# Keys are EC P-256, mode 0600; certificates are valid for 825 days (DAYS=... to change). Existing files are
# never overwritten: delete them first to re-issue. Never commit the .key files.
set -euo pipefail

if [[ $# -lt 2 ]]; then
    awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"
    exit 2
fi
out=$1
shift
days=${DAYS:-825}
mkdir -p "$out"
umask 077

san=""
for name in "$@"; do
    if [[ $name =~ ^[0-9.]+$ || $name == *:* ]]; then
        san+="IP:$name,"
    else
        san+="DNS:$name,"
    fi
done
san=${san%,}

key() {  # key FILE: a new EC P-256 private key (PKCS#8 PEM)
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null
}

issue() {  # issue NAME CN EXTENSIONS: NAME.key + NAME.pem signed by the CA
    local name=$1 cn=$2 ext=$3
    if [[ -e $out/$name.pem ]]; then
        echo "keep $out/$name.pem"
        return
    fi
    key "$out/$name.key"
    openssl req -new -key "$out/$name.key" -subj "/CN=$cn" -out "$out/$name.csr"
    printf '%b\n' "$ext" >"$out/$name.ext"
    openssl x509 -req -in "$out/$name.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
        -days "$days" -sha256 -extfile "$out/$name.ext" -out "$out/$name.pem" 2>/dev/null
    rm -f "$out/$name.csr" "$out/$name.ext"
    echo "wrote $out/$name.pem (CN=$cn)"
}

if [[ ! -e $out/ca.pem ]]; then
    key "$out/ca.key"
    openssl req -x509 -new -key "$out/ca.key" -sha256 -days "$days" -subj "/CN=hild-ca" \
        -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" \
        -out "$out/ca.pem"
    echo "wrote $out/ca.pem"
else
    echo "keep $out/ca.pem"
fi

leaf="basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature"
issue server "$1" "$leaf\nextendedKeyUsage=serverAuth\nsubjectAltName=$san"
for role in operator observer estop; do
    issue "$role" "$role" "$leaf\nextendedKeyUsage=clientAuth"
done
chmod 0644 "$out"/*.pem
echo "done. Move $out/ca.key off this machine; copy ca.pem and <role>.pem/.key to each station."
