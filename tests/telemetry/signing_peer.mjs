// MAVLink 2 signing against an independent implementation (node-mavlink's signer, Node's crypto SHA-256), for
// tests/mavlink_test.cpp. Usage: node signing_peer.mjs DIR
//   reads  DIR/key.hex (the 32-byte key, hex) and DIR/ours.bin (frames our encoder signed: u16 LE size, bytes);
//   writes DIR/ours.json (for each of ours: whether node-mavlink finds its signature right with the key),
//          DIR/theirs.bin (datagrams node-mavlink signed, u16 LE size, bytes) and DIR/theirs.json (the verdict each
//          must get from a receiver holding the key, in order, and the latitude of the ones it must take).
import { readFileSync, writeFileSync } from 'node:fs'
import { MavLinkProtocolV1, MavLinkProtocolV2, MavLinkPacketSignature, common, minimal } from 'node-mavlink'

const dir = process.argv[2]
const key = Buffer.from(readFileSync(`${dir}/key.hex`, 'utf8').trim(), 'hex')
const wrongKey = MavLinkPacketSignature.key('not the vehicle\'s passphrase')

function frames(bytes) {
  const out = []
  for (let at = 0; at + 2 <= bytes.length;) {
    const size = bytes.readUInt16LE(at)
    out.push(bytes.subarray(at + 2, at + 2 + size))
    at += 2 + size
  }
  return out
}

const ours = frames(readFileSync(`${dir}/ours.bin`)).map(f => new MavLinkPacketSignature(Buffer.from(f)).matches(key))
writeFileSync(`${dir}/ours.json`, JSON.stringify(ours))

const t0 = Date.UTC(2026, 10, 30, 12, 0, 0)  // ms; node-mavlink turns it into 10 us units since 2015
let seq = 0
function position(lat) {
  const g = new common.GlobalPositionInt()
  g.timeBootMs = 1000; g.lat = lat; g.lon = -919900000; g.alt = 80000; g.relativeAlt = 80000; g.hdg = 9000
  return g
}
function heartbeat() {
  const h = new minimal.Heartbeat()
  h.type = 2; h.autopilot = 3; h.baseMode = 209; h.systemStatus = 4; h.mavlinkVersion = 3
  return h
}
function signed(msg, signingKey, link, ms, sysid = 1) {
  const p = new MavLinkProtocolV2(sysid, 1, MavLinkProtocolV2.IFLAG_SIGNED)
  return p.sign(Buffer.from(p.serialize(msg, seq++ & 0xff)), link, signingKey, ms)
}
function plain(protocol, msg) { return Buffer.from(protocol.serialize(msg, seq++ & 0xff)) }

const cases = []
const add = (bytes, verdict, lat = null) => cases.push({ bytes, verdict, lat })
add(signed(heartbeat(), key, 1, t0), 'accepted')
const good = signed(position(146000001), key, 1, t0 + 1)
add(good, 'accepted', 146000001)
add(plain(new MavLinkProtocolV2(1, 1), position(146000002)), 'unsigned')
add(plain(new MavLinkProtocolV1(1, 1), position(146000003)), 'unsigned')
add(signed(position(146000004), wrongKey, 1, t0 + 2), 'bad_signature')
add(Buffer.from(good), 'replayed')  // the same packet again, as a recorder would send it
add(signed(position(146000005), key, 1, t0 + 1), 'replayed')  // a new packet with an old timestamp
add(signed(position(146000006), key, 1, t0 + 3).subarray(0, -5), 'cut_short')  // the signature cut short
add(signed(position(146000007), key, 1, t0 + 4), 'accepted', 146000007)
add(signed(position(146000008), key, 2, t0 - 61000), 'new_stream_refused')  // a new link, more than 1 min old
add(signed(position(146000009), key, 2, t0 + 5), 'accepted', 146000009)
add(signed(position(146000010), key, 1, t0 + 6, 2), 'accepted', 146000010)  // another system with the key: signed
const flipped = Buffer.from(signed(position(146000011), key, 1, t0 + 7))
flipped[flipped.length - 1] ^= 0x01  // one bit of the signature
add(flipped, 'bad_signature')

const chunks = []
for (const c of cases) {
  const size = Buffer.alloc(2)
  size.writeUInt16LE(c.bytes.length)
  chunks.push(size, c.bytes)
}
writeFileSync(`${dir}/theirs.bin`, Buffer.concat(chunks))
writeFileSync(`${dir}/theirs.json`, JSON.stringify(cases.map(c => ({ verdict: c.verdict, lat: c.lat }))))
