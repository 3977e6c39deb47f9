#!/bin/sh
# The proxy image's command: the template with the AAR_PROXY_* names replaced (only those:
# nginx's own $variables stay), then Debian's nginx in the foreground under /var/lib/nginx/
# (its temp folders body/, proxy/, ... as Debian lays them out).
set -eu
names=$(env | sed -n 's/^\(AAR_PROXY_[A-Z_]*\)=.*/${\1}/p' | tr '\n' ' ')
envsubst "$names" < /etc/nginx/aar-dock.conf.template > /etc/nginx/aar-dock.conf
exec nginx -p /var/lib/nginx/ -c /etc/nginx/aar-dock.conf -g 'daemon off;'
