// An independent OPC UA client (node-opcua, not asyncua) for tests/test_opcua_node.py.
//
//   node opcua_node_client.js URL USER PASSWORD
//
// Browses the cell, reads its scan count, subscribes to alarm events on the Server object,
// asks for a ConditionRefresh, acknowledges the high alarm as USER (its password travels
// encrypted with the server's certificate), and checks that an anonymous session is refused
// the same call. Prints one JSON object on stdout; exits 1 on any unexpected failure.
"use strict";
const {
    OPCUAClient, MessageSecurityMode, SecurityPolicy, UserTokenType, AttributeIds,
    constructEventFilter, TimestampsToReturn, callConditionRefresh, resolveNodeId,
} = require("node-opcua-client");

const [url, user, password] = process.argv.slice(2);
const FIELDS = ["EventId", "ConditionId", "ConditionName", "Severity", "Message",
    "ActiveState.Id", "AckedState.Id", "Retain", "ClientUserId", "SourceName"];

function connect() {
    return OPCUAClient.create({
        applicationName: "plchmi-node-check", endpointMustExist: false,
        securityMode: MessageSecurityMode.None, securityPolicy: SecurityPolicy.None,
        connectionStrategy: { maxRetry: 2, initialDelay: 200, maxDelay: 1000 },
    });
}

function until(predicate, what, ms = 30000) {
    return new Promise((resolve, reject) => {
        const started = Date.now();
        const tick = () => {
            const found = predicate();
            if (found) return resolve(found);
            if (Date.now() - started > ms) return reject(new Error(`no ${what} within ${ms} ms`));
            setTimeout(tick, 20);
        };
        tick();
    });
}

async function main() {
    const out = {};
    const client = connect();
    await client.connect(url);
    const session = await client.createSession({
        type: UserTokenType.UserName, userName: user, password });
    const namespaces = await session.readNamespaceArray();
    const ns = namespaces.indexOf("urn:plchmi:cispi_valve");
    const cell = `ns=${ns};s=cispi_valve`;
    const browsed = await session.browse(cell);
    out.children = browsed.references.map((r) => r.browseName.name).sort();
    const count = await session.read({ nodeId: `${cell}.Status.ScanCount`,
        attributeId: AttributeIds.Value });
    const raw = count.value.value;  // a UInt64 comes as [high, low] in node-opcua
    out.scanCount = Array.isArray(raw) ? raw[0] * 2 ** 32 + raw[1] : Number(raw);
    out.sourceTimestamp = count.sourceTimestamp ? count.sourceTimestamp.toISOString() : null;
    const written = await session.read({ nodeId: `${cell}.Valve V1.Outputs.O.WrittenValue` });
    out.writtenO = written.value.value;

    const subscription = await session.createSubscription2({
        requestedPublishingInterval: 50, requestedMaxKeepAliveCount: 20,
        requestedLifetimeCount: 600, publishingEnabled: true });
    const events = [];
    const item = await subscription.monitor(
        { nodeId: resolveNodeId("Server"), attributeId: AttributeIds.EventNotifier },
        { samplingInterval: 0, queueSize: 1000, filter: constructEventFilter(FIELDS),
          discardOldest: true }, TimestampsToReturn.Neither);
    item.on("changed", (fields) => {
        const e = {};
        FIELDS.forEach((name, i) => { e[name] = fields[i].value; });
        events.push(e);
    });
    await callConditionRefresh(session, subscription.subscriptionId);
    const high = await until(() => events.find((e) => e.ConditionName === "diagnosis:V1"),
        "refreshed high alarm");
    out.alarm = { severity: high.Severity, message: high.Message.text,
        active: high["ActiveState.Id"], acked: high["AckedState.Id"], retain: high.Retain,
        source: high.SourceName };

    // An anonymous session is refused the acknowledgement.
    const anonymousClient = connect();
    await anonymousClient.connect(url);
    const anonymous = await anonymousClient.createSession();
    const refused = await anonymous.acknowledgeCondition(high.ConditionId, high.EventId,
        "not me");
    out.anonymousAck = refused.name;
    await anonymous.close();
    await anonymousClient.disconnect();

    const status = await session.acknowledgeCondition(high.ConditionId, high.EventId,
        "node-opcua was here");
    out.ack = status.name;
    const acked = await until(() => events.find((e) => e.ConditionName === "diagnosis:V1"
        && e["AckedState.Id"] === true), "acknowledged event");
    out.acked = { user: acked.ClientUserId, active: acked["ActiveState.Id"],
        retain: acked.Retain };
    await subscription.terminate();
    await session.close();
    await client.disconnect();
    process.stdout.write(JSON.stringify(out) + "\n");
}

main().catch((err) => {
    process.stderr.write(`node-opcua check failed: ${err && err.stack || err}\n`);
    process.exit(1);
});
