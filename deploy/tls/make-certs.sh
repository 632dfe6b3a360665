#!/usr/bin/env bash
# Make a private CA and the TLS certificates of a dask cluster: scheduler, worker, client.
#
#   deploy/tls/make-certs.sh DIR
#
# Writes into DIR (created if missing, mode 700):
#   ca.pem                            the CA certificate every process trusts
#   scheduler.pem scheduler-key.pem   the scheduler's certificate and key
#   worker.pem    worker-key.pem      the workers' (one pair shared by every worker)
#   client.pem    client-key.pem      the runner's (`oceanlidar run --scheduler tls://...`)
#   private/ca-key.pem                the CA key: keep it, never mount or upload it
# Keys are mode 600. Existing files are never overwritten: remove DIR to start again.
#
# Every certificate may act as TLS server and client (dask connects in both directions:
# the scheduler dials workers, workers dial each other). dask checks the certificate chain
# both ways (mutual TLS) but not host names; the names below are for other tools and
# for clarity. Subject alternative names:
#   scheduler: scheduler (compose), oceanlidar-scheduler (the DaskCluster),
#              oceanlidar-sweep-scheduler (the DaskJob), localhost, 127.0.0.1
#   plus EXTRA_SANS, e.g. EXTRA_SANS="DNS:my-cluster-scheduler,IP:10.0.0.5".
# Validity: DAYS (default 365). Keys: ECDSA P-256.
set -euo pipefail

if [[ $# -ne 1 ]]; then
    echo "usage: $0 DIR" >&2
    exit 2
fi
dir=$1
days=${DAYS:-365}
extra=${EXTRA_SANS:+,${EXTRA_SANS}}

umask 077
mkdir -p "$dir/private"
chmod 700 "$dir" "$dir/private"
for name in ca.pem private/ca-key.pem scheduler.pem worker.pem client.pem; do
    if [[ -e "$dir/$name" ]]; then
        echo "$0: $dir/$name exists; remove $dir to make new certificates" >&2
        exit 1
    fi
done

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

key() {  # key FILE: a new ECDSA P-256 private key, mode 600
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1"
    chmod 600 "$1"
}

key "$dir/private/ca-key.pem"
openssl req -new -x509 -sha256 -days "$days" -key "$dir/private/ca-key.pem" \
    -subj "/CN=oceanlidar dask CA" \
    -addext "basicConstraints=critical,CA:TRUE,pathlen:0" \
    -addext "keyUsage=critical,keyCertSign,cRLSign" \
    -out "$dir/ca.pem"

leaf() {  # leaf ROLE SANS
    local role=$1 sans=$2
    key "$dir/$role-key.pem"
    openssl req -new -sha256 -key "$dir/$role-key.pem" -subj "/CN=dask-$role" \
        -out "$work/$role.csr"
    cat >"$work/$role.ext" <<EXT
basicConstraints=critical,CA:FALSE
keyUsage=critical,digitalSignature
extendedKeyUsage=serverAuth,clientAuth
subjectAltName=$sans
EXT
    openssl x509 -req -sha256 -days "$days" -in "$work/$role.csr" \
        -CA "$dir/ca.pem" -CAkey "$dir/private/ca-key.pem" \
        -set_serial "0x$(openssl rand -hex 16)" \
        -extfile "$work/$role.ext" -out "$dir/$role.pem" 2>/dev/null
    openssl verify -CAfile "$dir/ca.pem" "$dir/$role.pem" >/dev/null
}

leaf scheduler "DNS:scheduler,DNS:oceanlidar-scheduler,DNS:oceanlidar-sweep-scheduler,DNS:localhost,IP:127.0.0.1$extra"
leaf worker "DNS:worker,DNS:localhost,IP:127.0.0.1$extra"
leaf client "DNS:runner,DNS:client,DNS:localhost,IP:127.0.0.1"
chmod 644 "$dir"/*.pem
chmod 600 "$dir"/*-key.pem "$dir/private/ca-key.pem"

echo "certificates in $dir (valid $days days):" >&2
ls -l "$dir" >&2
