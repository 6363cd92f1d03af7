#!/usr/bin/env bash
# Builds the reference CFX SDK's model classes and tests/cfx_sdk/Check.cs with
# Debian's mono (mono-mcs, mono-runtime, libnewtonsoft-json5.0-cil) and runs
# the checker (decision 0095). The SDK is a checkout of
# github:IPCConnectedFactoryExchange/CFX at $CFX_SDK_DIR; it is copied to a
# temporary directory and never committed here.
#
#   CFX_SDK_DIR=/path/to/CFX tests/cfx_sdk/run.sh dump  OUT.json
#   CFX_SDK_DIR=/path/to/CFX tests/cfx_sdk/run.sh check DIR OUT.json
#
# Three changes make the model classes compile against Debian's Newtonsoft.Json
# 6.0.8 (the SDK pins 13.x); none is on the reading path:
#  - Utilities/JsonConvert.cs: TypeNameAssemblyFormatHandling.Simple (13.x) is
#    written as its 6.x name, TypeNameAssemblyFormat = FormatterAssemblyStyle.Simple
#    (how a written $type names its assembly);
#  - Utilities/AppLog.cs: SetupAmqpLogging's body (AMQPNetLite's trace hooks;
#    the transport is not built) is emptied;
#  - Structures/PCBInspection/*.cs: [JsonObject(ItemNullValueHandling = Ignore)]
#    (13.x; how nulls are written in PCB inspection structures) is dropped.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
: "${CFX_SDK_DIR:?set CFX_SDK_DIR to a checkout of github:IPCConnectedFactoryExchange/CFX}"
src="$CFX_SDK_DIR/CFX"
[ -f "$src/CFXEnvelope.cs" ] || { echo "no CFX/CFXEnvelope.cs under $CFX_SDK_DIR" >&2; exit 2; }
NJ=$(ls /usr/lib/mono/gac/Newtonsoft.Json/*/Newtonsoft.Json.dll /usr/lib/cli/Newtonsoft.Json-*/Newtonsoft.Json.dll 2>/dev/null | head -1)
[ -n "$NJ" ] || { echo "Newtonsoft.Json not found: apt-get install libnewtonsoft-json5.0-cil" >&2; exit 2; }
work=${CFX_SDK_BUILD:-$(mktemp -d /tmp/cfx-sdk-build.XXXXXX)}
mkdir -p "$work"
if [ ! -f "$work/Check.exe" ] || [ "$here/Check.cs" -nt "$work/Check.exe" ]; then
    rm -rf "$work/CFX"
    cp -r "$src" "$work/CFX"
    cd "$work"
    sed -i 's/JsonSettings.TypeNameAssemblyFormatHandling = Newtonsoft.Json.TypeNameAssemblyFormatHandling.Simple;/JsonSettings.TypeNameAssemblyFormat = System.Runtime.Serialization.Formatters.FormatterAssemblyStyle.Simple;/' CFX/Utilities/JsonConvert.cs
    perl -0pi -e 's/(private static void SetupAmqpLogging\(\)\s*\{).*?(\n        \}\n)/$1 return; $2/s' CFX/Utilities/AppLog.cs
    sed -i 's/\[JsonObject(ItemNullValueHandling = NullValueHandling.Ignore)\]//' CFX/Structures/PCBInspection/*.cs
    find CFX -name '*.cs' -not -path 'CFX/Transport/*' -not -path 'CFX/HelpContent/*' -not -path 'CFX/DataStructures/*' -print0 \
        | xargs -0 -I{} printf '"%s"\n' {} > files.txt
    mcs -nologo -target:library -nowarn:1591,618,612,1570,1587,1572,1573,1574,169,414,649,219,162,168 -out:CFX.dll -r:"$NJ" -r:System.Runtime.Serialization @files.txt >build.log 2>&1 \
        || { grep error build.log >&2; exit 1; }
    cp "$NJ" .
    mcs -nologo -out:Check.exe -r:CFX.dll -r:"$NJ" "$here/Check.cs"
    cd - >/dev/null
fi
exec mono "$work/Check.exe" "$@"
