// The CFX conformance checker (issue 34, decision 0095). Built against the
// reference C# SDK's model classes (github:IPCConnectedFactoryExchange/CFX,
// never committed here) by tests/cfx_sdk/run.sh, with Debian's mono and
// Newtonsoft.Json. Two modes:
//
//   Check.exe dump  OUT.json        the SDK's JSON shapes, by reflection through
//                                   Newtonsoft's own contract resolver: every
//                                   class under CFX.* (its JSON members, their
//                                   types, abstract or not, base class) and every
//                                   enum (its names, read as strings or numbers).
//   Check.exe check DIR OUT.json    every DIR/*.json (one CFX envelope each) read
//                                   1. with CFXEnvelope.FromJson (what the SDK's
//                                      AMQP receiver does), written back with ToJson;
//                                   2. strictly: the MessageBody on the class named
//                                      by MessageName, with TypeNameHandling=Auto and
//                                      MissingMemberHandling=Error.
//
// The outputs are the fixtures tests/it's CFX conformance test reads.
using System;
using System.Collections.Generic;
using System.IO;
using System.Linq;
using System.Reflection;
using Newtonsoft.Json;
using Newtonsoft.Json.Linq;
using Newtonsoft.Json.Serialization;

public static class Check
{
    static string TypeName(Type t)
    {
        Type u = Nullable.GetUnderlyingType(t);
        if (u != null) return TypeName(u) + "?";
        if (t.IsGenericType && t.GetGenericTypeDefinition() == typeof(List<>))
            return "List<" + TypeName(t.GetGenericArguments()[0]) + ">";
        if (t.IsArray) return "List<" + TypeName(t.GetElementType()) + ">";
        if (t.IsGenericType && t.GetGenericTypeDefinition() == typeof(Dictionary<,>))
            return "Dictionary<" + TypeName(t.GetGenericArguments()[0]) + "," + TypeName(t.GetGenericArguments()[1]) + ">";
        return t.FullName;
    }

    static int Dump(string outPath)
    {
        Assembly cfx = typeof(CFX.CFXEnvelope).Assembly;
        var settings = CFX.Utilities.CFXJsonSerializer.JsonSettings;
        var resolver = JsonSerializer.CreateDefault(settings).ContractResolver;
        var types = new JObject();
        foreach (Type t in cfx.GetExportedTypes().OrderBy(x => x.FullName, StringComparer.Ordinal))
        {
            if (t.FullName == null || !t.FullName.StartsWith("CFX.")) continue;
            if (t.FullName.StartsWith("CFX.Transport.") || t.FullName.StartsWith("CFX.Utilities.")) continue;
            if (t.IsGenericTypeDefinition || t.IsInterface) continue;
            var o = new JObject();
            if (t.IsEnum)
            {
                o["kind"] = "enum";
                bool asString = t.GetCustomAttributes(typeof(JsonConverterAttribute), true).Length > 0;
                o["as_string"] = asString;
                o["values"] = new JArray(Enum.GetNames(t));
            }
            else if (t.IsClass)
            {
                o["kind"] = "class";
                o["abstract"] = t.IsAbstract;
                o["base"] = t.BaseType == null ? null : t.BaseType.FullName;
                var props = new JObject();
                var contract = resolver.ResolveContract(t) as JsonObjectContract;
                if (contract != null)
                {
                    foreach (JsonProperty p in contract.Properties)
                    {
                        if (p.Ignored || !p.Writable) continue;
                        props[p.PropertyName] = TypeName(p.PropertyType);
                    }
                }
                o["members"] = props;
            }
            else continue;
            types[t.FullName] = o;
        }
        var root = new JObject();
        root["sdk_version"] = CFX.CFXEnvelope.CFXVERSION;
        root["types"] = types;
        File.WriteAllText(outPath, root.ToString(Formatting.Indented) + "\n");
        Console.WriteLine("dumped " + types.Count + " types of the CFX SDK " + CFX.CFXEnvelope.CFXVERSION);
        return 0;
    }

    static string Err(Exception e)
    {
        while (e.InnerException != null && e is TargetInvocationException) e = e.InnerException;
        return e.GetType().Name + ": " + e.Message;
    }

    static int CheckDir(string dir, string outPath)
    {
        var results = new JObject();
        int ok = 0, n = 0;
        foreach (string f in Directory.GetFiles(dir, "*.json").OrderBy(x => x, StringComparer.Ordinal))
        {
            n++;
            string json = File.ReadAllText(f);
            var r = new JObject();
            // 1. The SDK's own reading path.
            try
            {
                CFX.CFXEnvelope env = CFX.CFXEnvelope.FromJson(json);
                r["from_json"] = env.MessageBody is CFX.CFXMessage ? "ok" : "no CFXMessage body";
                r["round_trip"] = JObject.Parse(env.ToJson());
            }
            catch (Exception e) { r["from_json"] = Err(e); }
            // 2. Strict: unknown members are errors, $type where a member is abstract.
            try
            {
                JObject o = JObject.Parse(json);
                string name = (string)o["MessageName"];
                Type t = typeof(CFX.CFXEnvelope).Assembly.GetType(name);
                if (t == null) throw new Exception("no SDK class " + name);
                var strict = new JsonSerializerSettings
                {
                    TypeNameHandling = TypeNameHandling.Auto,
                    MissingMemberHandling = MissingMemberHandling.Error,
                };
                var body = JsonConvert.DeserializeObject(o["MessageBody"].ToString(), t, strict);
                var envOnly = (JObject)o.DeepClone();
                envOnly.Remove("MessageBody");
                JsonConvert.DeserializeObject<CFX.CFXEnvelope>(envOnly.ToString(), strict);
                r["strict"] = body == null ? "null body" : "ok";
            }
            catch (Exception e) { r["strict"] = Err(e); }
            if ((string)r["from_json"] == "ok" && (string)r["strict"] == "ok") ok++;
            results[Path.GetFileName(f)] = r;
        }
        var root = new JObject();
        root["sdk_version"] = CFX.CFXEnvelope.CFXVERSION;
        root["messages"] = results;
        File.WriteAllText(outPath, root.ToString(Formatting.Indented) + "\n");
        Console.WriteLine(ok + " of " + n + " messages read by the SDK (FromJson and strict)");
        return ok == n ? 0 : 1;
    }

    public static int Main(string[] args)
    {
        if (args.Length == 2 && args[0] == "dump") return Dump(args[1]);
        if (args.Length == 3 && args[0] == "check") return CheckDir(args[1], args[2]);
        Console.Error.WriteLine("usage: Check.exe dump OUT.json | Check.exe check DIR OUT.json");
        return 2;
    }
}
