-- The dissector itself: the generated tables above (NETWORK, SRDOS, SIMPLECAN, CRC,
-- CONSTANTS, VERDICT) are all it knows of the network. A post-dissector, so it decodes every CAN
-- frame whatever decodes it besides (Decode As CANopen included). Verdicts are reached on
-- the first pass over the trace, in order, and kept per frame for later passes.

local proto = Proto("cansafety", "CANopen Safety and SimpleCAN (" .. NETWORK .. ")")

local can_id = Field.new("can.id")
local can_len = Field.new("can.len")
local can_rtr = Field.new("can.flags.rtr")
local can_err = Field.new("can.flags.err")
local can_xtd = Field.new("can.flags.xtd")
local frame_time = Field.new("frame.time_epoch")

local f = {
  frame = ProtoField.string("cansafety.frame", "Safety frame"),
  srdo = ProtoField.string("cansafety.srdo", "SRDO (COB-ID 1/COB-ID 2)"),
  producer = ProtoField.string("cansafety.srdo.producer", "Producer"),
  consumers = ProtoField.string("cansafety.srdo.consumers", "Consumers"),
  verdict = ProtoField.string("cansafety.srdo.verdict",
    "Verdict on the pair this frame completes (EN 50325-5 7.1)"),
  valid = ProtoField.bool("cansafety.srdo.valid", "Pair valid"),
  plain_frame = ProtoField.framenum("cansafety.srdo.plain_frame", "Plain frame of the pair"),
  inverted_ok = ProtoField.bool("cansafety.srdo.inverted_ok",
    "Inverted frame is the plain frame bit by bit inverted (EN 50325-5 7.1.1)"),
  mismatch = ProtoField.bytes("cansafety.srdo.mismatch", "Bits not inverted (set bits)"),
  gap = ProtoField.double("cansafety.srdo.gap_ms", "Plain to inverted gap (ms)"),
  srvt = ProtoField.uint32("cansafety.srdo.srvt_ms", "SRVT (ms)"),
  srvt_exceeded = ProtoField.bool("cansafety.srdo.srvt_exceeded",
    "Gap at or over SRVT (EN 50325-5 7.1.2)"),
  period = ProtoField.double("cansafety.srdo.period_ms", "Period since the previous pair (ms)"),
  sct = ProtoField.uint32("cansafety.srdo.sct_ms", "SCT (ms)"),
  sct_exceeded = ProtoField.bool("cansafety.srdo.sct_exceeded",
    "Period at or over SCT (EN 50325-5 7.1.2)"),
  refresh = ProtoField.uint32("cansafety.srdo.refresh_ms", "Refresh time (ms)"),
  gfc = ProtoField.bool("cansafety.gfc", "Global fail-safe command (EN 50325-5 7.2)"),
  sc_kind = ProtoField.string("cansafety.simplecan", "SimpleCAN packet"),
  sc_id = ProtoField.uint8("cansafety.simplecan.sc_id", "SC-ID", base.HEX),
  sc_producer = ProtoField.string("cansafety.simplecan.producer", "Producer"),
  sc_value = ProtoField.uint32("cansafety.simplecan.value", "Value", base.HEX_DEC),
  sc_stamp = ProtoField.uint8("cansafety.simplecan.cycle_stamp", "Cycle stamp"),
  sc_master = ProtoField.uint8("cansafety.simplecan.master", "Master SC-ID", base.HEX),
  sc_cycle = ProtoField.uint16("cansafety.simplecan.cycle", "Cycle"),
  sc_offset = ProtoField.uint16("cansafety.simplecan.offset_us", "Offset into the last slot (us)"),
  sc_crc = ProtoField.uint24("cansafety.simplecan.crc", "CRC-24 received", base.HEX),
  sc_crc_computed = ProtoField.uint24("cansafety.simplecan.crc_computed",
    "CRC-24 computed with the node hash", base.HEX),
  sc_crc_ok = ProtoField.bool("cansafety.simplecan.crc_ok", "CRC good"),
  sc_problem = ProtoField.string("cansafety.simplecan.problem", "Not a valid packet"),
}
local field_list = {}
for _, field in pairs(f) do
  field_list[#field_list + 1] = field
end
proto.fields = field_list

local e = {
  fault = ProtoExpert.new("cansafety.fault", "Safety fault", expert.group.PROTOCOL,
    expert.severity.ERROR),
  missing = ProtoExpert.new("cansafety.missing", "Safety frame missing", expert.group.SEQUENCE,
    expert.severity.WARN),
  gfc = ProtoExpert.new("cansafety.gfc.expert", "Global fail-safe command",
    expert.group.PROTOCOL, expert.severity.WARN),
  repeated = ProtoExpert.new("cansafety.repeated", "CAN double reception",
    expert.group.SEQUENCE, expert.severity.NOTE),
}
proto.experts = { e.fault, e.missing, e.gfc, e.repeated }

-- The CRC of SimpleCAN (docs/simplecan.md section 4) bit by bit, MSB first, without final
-- XOR: the parameters are the Rust constant's (CRC above).
local function crc(octets)
  local value = CRC.init
  local top_bit = CRC.width - 1
  for _, octet in ipairs(octets) do
    for b = 7, 0, -1 do
      local input = bit.band(bit.rshift(octet, b), 1)
      local top = bit.band(bit.rshift(value, top_bit), 1)
      value = bit.band(bit.lshift(value, 1), CRC.mask)
      if input ~= top then
        value = bit.bxor(value, CRC.poly)
      end
    end
  end
  return value
end

do
  local check = { string.byte("123456789", 1, -1) }
  assert(crc(check) == CRC.check, "the SimpleCAN CRC of this dissector fails its check value")
end

-- The SRDOs by COB-ID: each identifier's SRDO and whether it is the plain or inverted frame.
local by_cob_id = {}
for _, srdo in ipairs(SRDOS) do
  by_cob_id[srdo.plain] = { srdo = srdo, plain = true }
  by_cob_id[srdo.inverted] = { srdo = srdo, plain = false }
end

-- State of the first pass, and what it concluded on each frame. Times are whole
-- nanoseconds since the second of the first frame, exact in a Lua number, so that a gap
-- exactly at its limit is judged as the node judges it (at the limit is exceeded).
local pending, missing, last_pair, results, first_second

local function reset()
  pending, missing, last_pair, results, first_second = {}, {}, {}, {}, nil
end
reset()

function proto.init()
  reset()
end

local function octets_equal(a, b)
  if #a ~= #b then
    return false
  end
  for i = 1, #a do
    if a[i] ~= b[i] then
      return false
    end
  end
  return true
end

local NS_PER_MS = 1000000

local function ms(nanoseconds)
  return nanoseconds / NS_PER_MS
end

-- The plain frame of an SRDO: the inverted frame is awaited; an earlier plain frame still
-- waiting is judged here (its inverted frame missing, or a plain frame repeated).
local function srdo_plain(srdo, number, at, data)
  local result = { kind = "SRDO plain", srdo = srdo }
  if missing[srdo.plain] then
    result.plain_frame = missing[srdo.plain]
    result.verdict = VERDICT.inverted_missing
    missing[srdo.plain] = nil
  end
  local waiting = pending[srdo.plain]
  if waiting then
    if octets_equal(waiting.data, data) then
      result.note = "repeat of frame " .. waiting.number .. " (CAN double reception), discarded"
      return result
    else
      result.plain_frame = waiting.number
      result.verdict = VERDICT.plain_repeated
    end
  end
  pending[srdo.plain] = { number = number, at = at, data = data }
  return result
end

-- The inverted frame of an SRDO: the pair's checks, in the order of the monitor's model.
local function srdo_inverted(srdo, at, data)
  local result = { kind = "SRDO inverted", srdo = srdo }
  local plain = pending[srdo.plain]
  if not plain then
    if missing[srdo.plain] then
      result.plain_frame = missing[srdo.plain]
      result.verdict = VERDICT.inverted_missing
      result.note = "too late for plain frame " .. missing[srdo.plain]
      missing[srdo.plain] = nil
    else
      result.verdict = "no plain frame before it"
    end
    return result
  end
  pending[srdo.plain] = nil
  result.plain_frame = plain.number
  local gap = at - plain.at
  local period = last_pair[srdo.plain] and plain.at - last_pair[srdo.plain]
  result.gap = ms(gap)
  result.period = period and ms(period)
  last_pair[srdo.plain] = plain.at
  if #plain.data == #data then
    local mismatch = {}
    result.inverted_ok = true
    for i = 1, #data do
      local bits = bit.band(bit.bxor(bit.bxor(plain.data[i], data[i]), 0xFF), 0xFF)
      mismatch[i] = string.char(bits)
      if bits ~= 0 then
        result.inverted_ok = false
      end
    end
    -- One octet per data octet: the field covers the inverted frame's data.
    result.mismatch = table.concat(mismatch)
  end
  result.srvt_exceeded = srdo.srvt_ms ~= nil and gap >= srdo.srvt_ms * NS_PER_MS
  result.sct_exceeded = srdo.sct_ms ~= nil and period ~= nil
    and period >= srdo.sct_ms * NS_PER_MS
  if result.inverted_ok == nil then
    result.verdict = VERDICT.lengths_differ
  elseif not result.inverted_ok then
    result.verdict = VERDICT.not_inverted
  elseif result.srvt_exceeded then
    result.verdict = VERDICT.srvt_exceeded
  elseif result.sct_exceeded then
    result.verdict = VERDICT.sct_exceeded
  else
    result.verdict = VERDICT.valid
  end
  return result
end

-- A SimpleCAN packet, checked in the order of docs/simplecan.md section 10.
local function simplecan(id, rtr, data)
  local sync = id == CONSTANTS.sync_id
  local result = { kind = sync and "SimpleCAN sync" or "SimpleCAN data" }
  if rtr then
    result.problem = "a remote frame on a SimpleCAN identifier"
    return result
  end
  if #data ~= CONSTANTS.packet_length then
    result.problem = "data length " .. #data .. ", not " .. CONSTANTS.packet_length
    return result
  end
  local sc_id = id
  if sync then
    sc_id = data[1]
    result.master = sc_id
    if sc_id < CONSTANTS.lowest_sc_id or sc_id > CONSTANTS.highest_sc_id then
      result.problem = "byte 0 is not an SC-ID (30h..7Fh)"
      return result
    end
  end
  result.sc_id = sc_id
  result.received_crc = data[6] * 65536 + data[7] * 256 + data[8]
  local hash = SIMPLECAN.hashes[sc_id]
  if not hash then
    result.problem = "no node hash for SC-ID " .. string.format("%02Xh", sc_id)
      .. " in the network file: the CRC cannot be checked"
    return result
  end
  local word = id * 16 + CONSTANTS.packet_length
  local fed = {
    math.floor(hash / 16777216) % 256, math.floor(hash / 65536) % 256,
    math.floor(hash / 256) % 256, hash % 256,
    math.floor(word / 256) % 256, word % 256,
    data[1], data[2], data[3], data[4], data[5],
  }
  result.computed_crc = crc(fed)
  result.crc_ok = result.computed_crc == result.received_crc
  if not result.crc_ok then
    result.problem = "bad CRC"
    return result
  end
  if sync then
    result.cycle = data[2] * 256 + data[3]
    result.offset = data[4] * 256 + data[5]
    if result.offset > CONSTANTS.max_offset_us then
      result.problem = "offset " .. result.offset .. " us is a whole slot or more"
    end
  else
    result.value = data[1] + data[2] * 256 + data[3] * 65536 + data[4] * 16777216
    result.stamp = data[5]
  end
  return result
end

-- Every plain frame whose SRVT ran out by `at` has its inverted frame missing, as the
-- monitor's model judges it when time passes; the verdict shows on the SRDO's next frame.
-- The inverted frame arriving now (`except`) is judged by its own gap instead.
local function expire(at, except)
  for _, srdo in ipairs(SRDOS) do
    local waiting = pending[srdo.plain]
    if srdo ~= except and waiting and srdo.srvt_ms
        and at - waiting.at >= srdo.srvt_ms * NS_PER_MS then
      pending[srdo.plain] = nil
      missing[srdo.plain] = waiting.number
    end
  end
end

-- The time of the frame being dissected, in nanoseconds since the first frame's second.
local function now()
  local time = frame_time().value
  first_second = first_second or time.secs
  return (time.secs - first_second) * 1000000000 + time.nsecs
end

-- Whether `id` is one this dissector decodes: an SRDO of the file, the GFC, SimpleCAN.
local function ours(id)
  return by_cob_id[id] ~= nil or id == CONSTANTS.gfc_id
    or (SIMPLECAN ~= nil and (id == CONSTANTS.sync_id
      or (id >= CONSTANTS.lowest_sc_id and id <= CONSTANTS.highest_sc_id)))
end

local function judge(number, at, id, rtr, data)
  local role = by_cob_id[id]
  if role and not rtr then
    if role.plain then
      return srdo_plain(role.srdo, number, at, data)
    end
    return srdo_inverted(role.srdo, at, data)
  end
  if id == CONSTANTS.gfc_id and not rtr then
    return { kind = "GFC", length = #data }
  end
  if SIMPLECAN and (id == CONSTANTS.sync_id
      or (id >= CONSTANTS.lowest_sc_id and id <= CONSTANTS.highest_sc_id)) then
    return simplecan(id, rtr, data)
  end
  return nil
end

local FAULTS = {
  [VERDICT.not_inverted] = true, [VERDICT.lengths_differ] = true,
  [VERDICT.srvt_exceeded] = true, [VERDICT.sct_exceeded] = true,
  [VERDICT.plain_repeated] = true,
}

local function show_srdo(tree, range, result, pinfo)
  local srdo = result.srdo
  tree:add(f.srdo, range, srdo.name)
  if srdo.producer then
    tree:add(f.producer, range, srdo.producer)
  end
  if srdo.consumers then
    tree:add(f.consumers, range, srdo.consumers)
  end
  if srdo.refresh_ms then
    tree:add(f.refresh, range, srdo.refresh_ms)
  end
  local info = result.kind .. " " .. srdo.name
  if result.note then
    tree:add_proto_expert_info(e.repeated, result.note)
    info = info .. ": " .. result.note
  end
  if result.plain_frame then
    tree:add(f.plain_frame, range, result.plain_frame)
  end
  if result.verdict then
    local item = tree:add(f.verdict, range, result.verdict)
    tree:add(f.valid, range, result.verdict == VERDICT.valid)
    info = info .. ": " .. result.verdict
    if FAULTS[result.verdict] then
      item:add_proto_expert_info(e.fault, srdo.name .. ": " .. result.verdict)
    elseif result.verdict ~= VERDICT.valid then
      item:add_proto_expert_info(e.missing, srdo.name .. ": " .. result.verdict)
    end
  elseif result.kind == "SRDO plain" and not result.note then
    info = info .. ", awaiting the inverted frame"
  end
  if result.inverted_ok ~= nil then
    tree:add(f.inverted_ok, range, result.inverted_ok)
    if #result.mismatch == range:len() then
      tree:add(f.mismatch, range, result.mismatch)
    end
  end
  if result.gap then
    tree:add(f.gap, range, result.gap)
    info = info .. string.format(", gap %.3f ms", result.gap)
    if srdo.srvt_ms then
      tree:add(f.srvt, range, srdo.srvt_ms)
      tree:add(f.srvt_exceeded, range, result.srvt_exceeded)
      info = info .. " (SRVT " .. srdo.srvt_ms .. " ms)"
    end
  end
  if result.period then
    tree:add(f.period, range, result.period)
    info = info .. string.format(", period %.3f ms", result.period)
    if srdo.sct_ms then
      tree:add(f.sct, range, srdo.sct_ms)
      tree:add(f.sct_exceeded, range, result.sct_exceeded)
      info = info .. " (SCT " .. srdo.sct_ms .. " ms)"
    end
  end
  pinfo.cols.protocol:set("SRDO")
  pinfo.cols.info:set(info)
end

local function show_simplecan(tree, range, result, pinfo)
  tree:add(f.sc_kind, range, result.kind)
  local info = result.kind
  if result.master then
    tree:add(f.sc_master, range, result.master)
  end
  if result.sc_id then
    tree:add(f.sc_id, range, result.sc_id)
    info = info .. string.format(" SC-ID %02Xh", result.sc_id)
    local producer = SIMPLECAN.producers[result.sc_id]
    if producer then
      tree:add(f.sc_producer, range, producer)
    end
  end
  if result.received_crc then
    tree:add(f.sc_crc, range, result.received_crc)
  end
  if result.computed_crc then
    tree:add(f.sc_crc_computed, range, result.computed_crc)
    tree:add(f.sc_crc_ok, range, result.crc_ok)
  end
  if result.value then
    tree:add(f.sc_value, range, result.value)
    tree:add(f.sc_stamp, range, result.stamp)
    info = info .. string.format(": value %08Xh, cycle stamp %d", result.value, result.stamp)
  end
  if result.cycle then
    tree:add(f.sc_cycle, range, result.cycle)
    tree:add(f.sc_offset, range, result.offset)
    info = info .. string.format(": cycle %d, offset %d us", result.cycle, result.offset)
  end
  if result.problem then
    local item = tree:add(f.sc_problem, range, result.problem)
    if result.crc_ok == false then
      item:add_proto_expert_info(e.fault, result.kind .. ": " .. result.problem)
    end
    info = info .. ": " .. result.problem
  end
  pinfo.cols.protocol:set("SimpleCAN")
  pinfo.cols.info:set(info)
end

function proto.dissector(tvb, pinfo, tree)
  local id_info = can_id()
  if not id_info then
    return
  end
  local result = results[pinfo.number]
  if not pinfo.visited and result == nil then
    local id = id_info.value
    local role = by_cob_id[id]
    -- Every frame tells that time passed; only those of the file are read further.
    local at = now()
    if next(pending) ~= nil then
      expire(at, role and not role.plain and role.srdo)
    end
    local rtr = can_rtr() and can_rtr().value or false
    local err = can_err() and can_err().value or false
    local xtd = can_xtd() and can_xtd().value or false
    if err or xtd or not ours(id) then
      results[pinfo.number] = false
      return
    end
    local length = can_len() and can_len().value or 0
    local start = id_info.offset + 8
    if rtr or length > 8 or start + length > tvb:len() then
      length = 0
    end
    local data = {}
    for i = 0, length - 1 do
      data[#data + 1] = tvb(start + i, 1):uint()
    end
    result = judge(pinfo.number, at, id, rtr, data) or false
    results[pinfo.number] = result
  end
  if not result then
    return
  end
  local length = (can_len() and can_len().value or 0)
  local start = id_info.offset + 8
  local range
  if length > 0 and start + length <= tvb:len() then
    range = tvb(start, length)
  else
    range = tvb(id_info.offset, 4)
  end
  local subtree = tree:add(proto, range)
  subtree:add(f.frame, range, result.kind)
  if result.srdo then
    show_srdo(subtree, range, result, pinfo)
  elseif result.kind == "GFC" then
    subtree:add(f.gfc, range, true)
    local words = "GFC (global fail-safe command): every safety node in Operational goes to its safe state"
    if result.length ~= 0 then
      words = words .. "; " .. result.length .. " data byte(s), the GFC has none"
    end
    subtree:add_proto_expert_info(e.gfc, words)
    pinfo.cols.protocol:set("GFC")
    pinfo.cols.info:set(words)
  else
    show_simplecan(subtree, range, result, pinfo)
  end
end

register_postdissector(proto)
